"""The neural field: networks (swappable backbones), losses (plugins), the Lightning module and data, and
``Field``, the one object every geometric stage queries."""
