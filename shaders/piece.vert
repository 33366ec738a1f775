#version 430 core
// Piece patches: one vertex of a quad patch, skinned by linear blend skinning (paper 4.3).
// Defines accepted (inserted after the #version line by worker.render.shaders): none.

layout(location = 0) in vec3 in_position;  // prototype (model) space
layout(location = 1) in vec3 in_normal;
layout(location = 2) in vec2 in_st;
layout(location = 3) in ivec4 in_joints;   // joint indices of the piece's skeleton
layout(location = 4) in vec4 in_weights;   // sum to 1

// One instance buffer for the forest, sorted by piece type; a draw call covers the
// instances [u_base_instance, u_base_instance + instance count).
struct Instance {
    mat4 transform;   // topological transform (prototype -> world), unskinned
    int bone_offset;  // first palette entry of the instance's bones
    int tile_offset;  // first entry of the instance's tile indices (one per quad)
    int id;           // instance index in the scene (PointInstancer order)
    int piece_type;   // index of the piece's prototype (read by shaders/cull.comp)
};
layout(std430, binding = 0) readonly buffer Instances { Instance instances[]; };
// The forest's bone palette: skinning matrices mapping prototype space straight to world.
layout(std430, binding = 1) readonly buffer Palette { mat4 bones[]; };

// With u_culled, the instances kept by the cull pass (worker.render.instance_cull): a draw's
// instance k is instances[visible[u_base_instance + k]].
layout(std430, binding = 7) readonly buffer Visible { int visible[]; };

uniform int u_base_instance;
uniform bool u_culled;
uniform bool u_skinning;  // false: place the rest piece with its topological transform

out Vertex {
    vec3 position;  // world
    vec3 normal;    // world, unit
    vec2 st;
    int slot;       // index into instances[]
} vs_out;

void main() {
    int slot = u_culled ? visible[u_base_instance + gl_InstanceID]
                        : u_base_instance + gl_InstanceID;
    Instance inst = instances[slot];
    mat4 m;
    if (u_skinning) {
        // the instance's bone offset added to the blend indices
        ivec4 j = in_joints + inst.bone_offset;
        m = in_weights.x * bones[j.x] + in_weights.y * bones[j.y]
          + in_weights.z * bones[j.z] + in_weights.w * bones[j.w];
    } else {
        m = inst.transform;
    }
    vs_out.position = (m * vec4(in_position, 1.0)).xyz;
    // inverse transpose: right for any blended (not only similarity) matrix
    vs_out.normal = normalize(transpose(inverse(mat3(m))) * in_normal);
    vs_out.st = in_st;
    vs_out.slot = slot;
}
