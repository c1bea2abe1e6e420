"""Virtual calibration: fit pose reconstruction on simulated read-outs, report the error."""
