"""The ground floor: helpers every other floor may use (atomic writes, the plane palette,
optional libraries, C libraries' stderr). Imports nothing else of the project."""
