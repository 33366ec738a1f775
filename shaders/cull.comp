#version 430 core
// Per-instance culling before the draws (worker/render/instance_cull.py): one invocation per piece
// instance tests a sphere around its posed skeleton against the view frustum and, with
// u_min_pixels > 0, drops pieces thinner on screen than that many pixels (a twig far away).
// Survivors are appended to their piece type's run of ``visible`` and counted straight into
// that type's indirect draw command, so no count comes back to the CPU.
// Defines accepted: none.

layout(local_size_x = 64) in;

struct Instance {  // as shaders/piece.vert
    mat4 transform;
    int bone_offset;
    int tile_offset;
    int id;
    int piece_type;
};
// What the bound needs of a piece type: its joints' rest origins (prototype space) and
// how far its surface lies from the polyline through them at rest (its tube radius).
struct PieceBound {
    vec4 joints[5];  // MAX_JOINTS; xyz
    int n_joints;
    float radius;
    int first;       // the type's first slot in ``visible`` (its first instance slot)
    int pad;
};
// DrawArraysIndirectCommand as moderngl strides it (five uints)
struct Command {
    uint count;
    uint instance_count;
    uint first;
    uint base_instance;
    uint pad;
};

layout(std430, binding = 0) readonly buffer Instances { Instance instances[]; };
layout(std430, binding = 1) readonly buffer Palette { mat4 bones[]; };
layout(std430, binding = 3) buffer Commands { Command commands[]; };
layout(std430, binding = 6) readonly buffer Pieces { PieceBound pieces[]; };
layout(std430, binding = 7) writeonly buffer Visible { int visible[]; };

uniform int u_count;        // instances
uniform vec3 u_camera;      // world
uniform vec3 u_forward;     // unit view direction: depth, not distance, sizes a pixel
uniform vec4 u_frustum[6];  // world planes (unit normal, offset), inside where dot >= 0
uniform float u_alpha;      // Phong shape factor: the surface bulges by at most 2 alpha r
uniform bool u_ortho;       // the sun's view: a pixel is u_pixel metres at any distance
uniform float u_pixel;      // perspective: metres per pixel per metre of distance
uniform float u_min_pixels; // 0: the frustum test alone

void main() {
    // a dispatch over 4 M instances spreads its groups over y as well
    int i = int(gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x
                + gl_GlobalInvocationID.x);
    if (i >= u_count) {
        return;
    }
    Instance inst = instances[i];
    PieceBound pb = pieces[inst.piece_type];
    vec3 lo = vec3(3.0e38);
    vec3 hi = vec3(-3.0e38);
    for (int j = 0; j < pb.n_joints; ++j) {
        vec3 p = (bones[inst.bone_offset + j] * vec4(pb.joints[j].xyz, 1.0)).xyz;
        lo = min(lo, p);
        hi = max(hi, p);
    }
    // the tube's rest radius (the whole prototype's) at the root bone's scale; terminals may
    // scale up to ~1.3x the root but carry thinner rims, and skinned tubes stay within
    // 1.011x of this (measured on oak, willow, spruce and birch in wind): 1.25x covers both
    float thick = pb.radius * length(bones[inst.bone_offset][0].xyz);
    vec3 c = 0.5 * (lo + hi);
    float r = 0.5 * length(hi - lo) + 1.25 * thick * (1.0 + 2.0 * u_alpha);
    for (int k = 0; k < 6; ++k) {
        if (dot(u_frustum[k].xyz, c) + u_frustum[k].w < -r) {
            return;
        }
    }
    if (u_min_pixels > 0.0) {
        // metres per pixel at the sphere's nearest depth (off the axis a perspective view
        // shows a thing larger than its distance says, never smaller than its depth says)
        float px = u_ortho ? u_pixel : max(dot(c - u_camera, u_forward) - r, 0.0) * u_pixel;
        if (2.0 * thick < u_min_pixels * px) {
            return;
        }
    }
    uint k = atomicAdd(commands[inst.piece_type].instance_count, 1u);
    visible[pb.first + int(k)] = i;
}
