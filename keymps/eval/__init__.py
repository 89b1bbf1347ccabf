"""`keymps eval`: the paper's metric D, benchmark suites, ground truth, methods, runner and reports."""
