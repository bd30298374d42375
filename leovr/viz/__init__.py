"""Rerun recordings of sequences and refinement runs."""
