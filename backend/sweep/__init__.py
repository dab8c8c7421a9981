"""`coplanar sweep`: a matrix of runs (matrix.py), each run by `backend.headless` in its own
folder, in-process or as Ray tasks (runner.py), and the results as rows (results.py), a table
(table.py) and plots (plots.py)."""
