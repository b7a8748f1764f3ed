"""Closed forms of the paper's theorems (``theory``) and statistics over seeds (``stats``)."""
