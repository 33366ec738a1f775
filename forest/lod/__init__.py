"""Levels of detail of a tree, made from its pieces (the paper's idea: few low-poly pieces,
detail only near the camera): :mod:`forest.lod.select` picks what each level keeps,
:mod:`forest.lod.cards` makes the crown cards of the far level, :mod:`forest.usd.lod` writes
the levels as a ``lod`` variant set on each skinned tree."""
