"""Velocity filters, observers and friction estimation of the book, and the estimator node."""
