"""Tests of the degrade package (docs/degradation.md)."""
