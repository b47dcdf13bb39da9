"""gymnasium environments driven by mjkin (registered on import)."""
