"""Tests of the degrade package (SPEC §10)."""
