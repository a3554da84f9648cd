"""Operators, one per file; the extension's entry point (the top-level ``__init__.py``) gathers them."""
