"""interlocking-forest: trees from instanceable, interlocking quad-mesh pieces."""

__version__ = "0.7.0"
