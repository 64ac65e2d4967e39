"""Residual evaluation, symptoms and diagnostic reasoning (issue 9)."""
