"""MJCF models shipped with mjkin (package data; see ``mjkin.bundled_models()``)."""
