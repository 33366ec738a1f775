"""Every numeric tolerance of the library, in one place, with the reason for its value."""

# Tests compare rims relative to the tree's size (the contract): 1e-5 of the size for
# positions and 1e-4 for normals leave room for float32 storage in USD (about 6e-8 relative).
TEST_RIM_POSITION_REL = 1e-5
TEST_RIM_NORMAL_ABS = 1e-4
# Normals captured from the GPU come from float32 skinning matrices whose scales span three
# orders of magnitude in a pipe-model tree (trunk to twig): 1.1e-4 seen on llvmpipe; 2e-4 rad
# is 0.01 degrees, far below what shading shows.
TEST_RIM_NORMAL_GPU_ABS = 2e-4

# UsdGeom.PointInstancer stores positions/orientations/scales as float32: its reconstruction of
# a float64 transform agrees to about 1e-7 of the transform's magnitude; 1e-6 is the contract.
INSTANCE_TRANSFORM_REL = 1e-6

# A similarity's three column norms agree to this before we call it uniformly scaled.
SIMILARITY_SCALE_REL = 1e-9
