"""An engine run headless to its output folder: what `coplanar run` does and every run of
`coplanar sweep` (DESIGN §7)."""
