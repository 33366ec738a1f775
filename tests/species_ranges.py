"""Typical figures of each species preset (``shared/SPECIES.md``): height and DBH in metres,
crown width over height. Tests allow SLACK around them: the table gives typical ranges of
mature open-grown trees, not rules."""

SLACK = 0.15

SPECIES = {
    # name: (height range, DBH range, crown ratio range)
    "oak": ((20, 35), (0.8, 1.8), (0.8, 1.1)),
    "almond": ((4, 9), (0.2, 0.4), (0.8, 1.2)),
    "birch": ((15, 25), (0.3, 0.5), (0.35, 0.5)),
    "pine": ((20, 35), (0.4, 1.0), (0.3, 0.5)),
    "spruce": ((30, 50), (0.6, 1.5), (0.25, 0.4)),
    "willow": ((10, 20), (0.5, 1.0), (0.9, 1.3)),
    "poplar": ((25, 30), (0.5, 1.0), (0.12, 0.25)),
    "hazel": ((3, 6), (0.05, 0.15), (0.8, 1.2)),
}

# Twigs end thin whatever the tree's size (shared/SPECIES.md): the rims that end branches, 95th
# percentile of their diameters (the rest are knots of shed branches and the leader's top)
TIP_DIAMETER_MAX = 0.01
# Seen from above a broadleaf's crown is round, not a fan: extent across over extent along
ROUND_CROWNS = ("oak", "almond", "birch", "willow", "poplar", "hazel")
ROUNDNESS_MIN = 0.75
# Pedunculate oak: forks low (crown base over height) and stays within its bark budget
OAK_CROWN_BASE = (0.2, 0.35)
OAK_BARK_TRIANGLES_MAX = 110_000


def within(value: float, lo_hi: tuple[float, float]) -> bool:
    lo, hi = lo_hi
    return lo * (1 - SLACK) <= value <= hi * (1 + SLACK)


# Leaf-card length of each species in metres (SPECIES.md's leaf or needle length; a card is one
# leaf, or for the conifers one needle's length): the figures tests read it from the USD.
LEAF_CARD_M = {
    "oak": (0.07, 0.14),
    "birch": (0.03, 0.07),
    "poplar": (0.05, 0.10),
    "almond": (0.07, 0.12),
    "hazel": (0.06, 0.12),
    "willow": (0.08, 0.15),
    "pine": (0.04, 0.07),
    "spruce": (0.01, 0.025),
}
