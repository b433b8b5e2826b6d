"""Data sets (joint readings + measurements) and the CSV format of every sensor."""
