"""Simulated experiments: the paper's, messy real-like sessions, sensor data."""
