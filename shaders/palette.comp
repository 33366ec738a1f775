#version 430 core
// The bone palette by forward kinematics (forest/growth/rig.py, worker/render/bone_kinematics.py):
// one invocation per bone of one hierarchy level; the levels are dispatched in order, so a
// bone's parent is done before it. local = Tr(t) R(q) S(s); G = G_parent local; the palette
// entry is G inv(J). Every bone of a level reads its parent's G as written, so a child's root
// and its parent's terminal agree exactly (rims meet).
// Defines accepted: none.

layout(local_size_x = 64) in;

// Bones in level order (the order of ``globals``), as worker.render.bone_kinematics.BONE_DTYPE.
struct Bone {
    vec4 translation_scale;  // local translation (xyz) and uniform scale (w)
    vec4 fixed_rotation;     // xyzw, the rotation where ``rotation`` < 0 (an instance's root)
    int parent;              // position of the parent in level order, -1 for a tree's root
    int rotation;            // row of this frame's rotations, or -1
    int palette;             // palette entry (the bone's index in the scene)
    int rest;                // row of inverse_rest
};
// binding points 0 and 2 are the draws' instances and tiles, rebound after this pass; 3, 4
// and 5 (capture, clouds, order) are left alone
layout(std430, binding = 0) readonly buffer Bones { Bone bones[]; };
layout(std430, binding = 1) writeonly buffer Palette { mat4 palette[]; };
layout(std430, binding = 2) readonly buffer Rotations { vec4 rotations[]; };
layout(std430, binding = 6) readonly buffer InverseRest { mat4 inverse_rest[]; };
layout(std430, binding = 7) buffer Globals { mat4 globals[]; };

uniform int u_first;  // this level's first position in level order
uniform int u_count;  // its bones

mat3 quaternion_matrix(vec4 q) {
    q = normalize(q);
    float x = q.x, y = q.y, z = q.z, w = q.w;
    // column by column
    return mat3(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + z * w), 2.0 * (x * z - y * w),
                2.0 * (x * y - z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + x * w),
                2.0 * (x * z + y * w), 2.0 * (y * z - x * w), 1.0 - 2.0 * (x * x + y * y));
}

void main() {
    int k = int(gl_GlobalInvocationID.x);
    if (k >= u_count) {
        return;
    }
    int i = u_first + k;
    Bone b = bones[i];
    vec4 q = b.rotation >= 0 ? rotations[b.rotation] : b.fixed_rotation;
    mat3 r = quaternion_matrix(q) * b.translation_scale.w;
    mat4 local = mat4(vec4(r[0], 0.0), vec4(r[1], 0.0), vec4(r[2], 0.0),
                      vec4(b.translation_scale.xyz, 1.0));
    mat4 g = b.parent >= 0 ? globals[b.parent] * local : local;
    globals[i] = g;
    palette[b.palette] = g * inverse_rest[b.rest];
}
