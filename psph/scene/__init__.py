"""Scenes: TOML files validated into frozen dataclasses."""
