"""calibrate(), checking on new data, result files."""
