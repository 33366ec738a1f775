"""pydantic v2 models of everything that crosses a wire; JSON Schema exports live in ``json/``."""
