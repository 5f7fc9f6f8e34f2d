"""Perception: registration, scanning, the reconstruction and its evaluation."""
