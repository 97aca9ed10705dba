"""Placeholder: filled by later issues (see the README roadmap)."""
