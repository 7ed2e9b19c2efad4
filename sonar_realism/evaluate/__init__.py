"""Realism evaluation: the paper's CNN real/sim score (Table I) and stronger metrics."""
