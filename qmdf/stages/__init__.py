"""The built-in stages, one module each. They stay thin: read artifacts, call geometry code, write artifacts."""
