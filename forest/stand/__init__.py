"""Mixed forests: a recipe's species layers placed over terrain (``recipes``, ``terrain``,
``place``), then grown layer by layer (``generate``); :mod:`forest.usd.stand` writes them."""
