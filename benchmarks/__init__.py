"""Harness, metrics, cell-selection policies, reports and the command line."""
