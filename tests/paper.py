"""Figures from the paper that tests check against."""

# Table "number of landmarks updated" (DESIGN §3): items / params of Monte-Carlo sequence b.
PAPER_COUNTS_B = {
    "P-wo": (100, 350),
    "P-r": (101, 353),
    "P-w": (51, 303),
    "PL-wo": (120, 430),
    "PL-r": (121, 433),
    "PL-w": (51, 303),
}
