"""Seed sweeps, measurement planning, validation, session hold-outs, HTML reports."""
