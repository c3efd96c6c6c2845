"""Launcher, parameter tool and the rwpend command line."""
