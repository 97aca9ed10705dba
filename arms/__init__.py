"""Arm models."""
