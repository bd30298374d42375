"""Pipelines that run over whole sequences and write outputs."""
