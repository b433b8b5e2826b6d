"""Measurement models (cable, position, pose, markers, sessions, contact, camera) and the closed-form starts of their extras."""
