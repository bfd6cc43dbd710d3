"""Swappable components the stages use (degradations now; backbones and losses with the field)."""
