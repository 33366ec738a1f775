"""Every numeric tolerance of the library, in one place, with the reason for its value."""

# Tests compare rims relative to the tree's size (the contract): 1e-5 of the size for
# positions and 1e-4 for normals leave room for float32 storage in USD (about 6e-8 relative).
TEST_RIM_POSITION_REL = 1e-5
TEST_RIM_NORMAL_ABS = 1e-4
# Normals captured from the GPU come from float32 skinning matrices whose scales span three
# orders of magnitude in a pipe-model tree (trunk to twig): 1.1e-4 seen on llvmpipe; 2e-4 rad
# is 0.01 degrees, far below what shading shows. (Each point is compared with its partner
# across the rim, not merely the nearest point: see tests/worker/test_render_gl.largest_gap.)
TEST_RIM_NORMAL_GPU_ABS = 2e-4

# UsdGeom.PointInstancer stores positions/orientations/scales as float32: its reconstruction of
# a float64 transform agrees to about 1e-7 of the transform's magnitude; 1e-6 is the contract.
INSTANCE_TRANSFORM_REL = 1e-6

# A similarity's three column norms agree to this before we call it uniformly scaled.
SIMILARITY_SCALE_REL = 1e-9

# Compact wind (forest.growth.rig): a palette rebuilt in float64 from float32 joint rotations
# agrees with the generator's to this fraction of the forest's size (float32 quaternions are
# rotations to about 6e-8 rad; measured 1.5e-8 to 6e-9 of the size on almond and oak).
PALETTE_REBUILT_REL = 1e-6
# The same palette by forward kinematics in float32 on the GPU (shaders/palette.comp) agrees
# with numpy's to this fraction of the largest world coordinate: rounding of world-space
# translations accumulates over the hierarchy's 40-60 levels (measured 5.4e-7 at 150 m and
# 4.2e-7 at 11 m on llvmpipe; float32's own spacing is 6e-8).
PALETTE_GPU_REL = 2e-6
