#version 430 core
// Phong tessellation of quads (paper 4.4, after Boubekeur and Alexa): the bilinear point of
// the four corners is projected onto each corner's tangent plane, the projections blended
// with the same bilinear weights, and the result mixed with the bilinear point by the shape
// factor alpha. Normals are interpolated bilinearly. The patch's tile index is looked up
// here with gl_PrimitiveID (the patch, i.e. quad, index within the piece; paper 5.1).
// Defines accepted: CAPTURE (append every evaluated vertex to a storage buffer, for tests).

// fractional spacing: a level is a continuous function of the distance, so the ulp-level
// difference between a parent's and a child's skinned rim moves tessellated vertices by
// ulps instead of switching an integer level on one side only.
layout(quads, fractional_odd_spacing, ccw) in;

in ControlPoint {
    vec3 position;
    vec3 normal;
    vec2 st;
    int slot;
} te_in[];

out Surface {
    vec3 position;
    vec3 normal;
    vec2 st;
    flat int tile;
    flat int instance;
    flat int quad;
} te_out;

struct Instance {
    mat4 transform;
    int bone_offset;
    int tile_offset;
    int id;
    int piece_type;
};
layout(std430, binding = 0) readonly buffer Instances { Instance instances[]; };
// Every instance's tile indices, one int per quad, instance after instance.
layout(std430, binding = 2) readonly buffer Tiles { int tiles[]; };

#ifdef CAPTURE
struct Captured {
    vec4 position;  // xyz world
    vec4 normal;    // xyz world
    vec4 coord;     // gl_TessCoord.xy, gl_TessLevelInner[0..1]
    vec4 outer;     // gl_TessLevelOuter[0..3]
    ivec4 ids;      // instance id, patch, tile, 0
};
layout(std430, binding = 3) buffer Capture {
    uint count;
    uint capacity;
    uint pad0;
    uint pad1;
    Captured captured[];
};
#endif

uniform mat4 u_view_projection;
uniform float u_alpha;  // Phong shape factor: 0 bilinear, 1 full projection

vec3 project(vec3 q, vec3 p, vec3 n) {
    return q - dot(q - p, n) * n;
}

void main() {
    float u = gl_TessCoord.x;
    float v = gl_TessCoord.y;
    // bilinear weights of the corners at (0,0) (0,1) (1,1) (1,0)
    vec4 w = vec4((1.0 - u) * (1.0 - v), (1.0 - u) * v, u * v, u * (1.0 - v));
    vec3 p = w.x * te_in[0].position + w.y * te_in[1].position
           + w.z * te_in[2].position + w.w * te_in[3].position;
    vec3 phong = w.x * project(p, te_in[0].position, te_in[0].normal)
               + w.y * project(p, te_in[1].position, te_in[1].normal)
               + w.z * project(p, te_in[2].position, te_in[2].normal)
               + w.w * project(p, te_in[3].position, te_in[3].normal);
    vec3 position = mix(p, phong, u_alpha);
    vec3 normal = normalize(w.x * te_in[0].normal + w.y * te_in[1].normal
                          + w.z * te_in[2].normal + w.w * te_in[3].normal);
    Instance inst = instances[te_in[0].slot];
    int tile = tiles[inst.tile_offset + gl_PrimitiveID];

    te_out.position = position;
    te_out.normal = normal;
    te_out.st = w.x * te_in[0].st + w.y * te_in[1].st + w.z * te_in[2].st + w.w * te_in[3].st;
    te_out.tile = tile;
    te_out.instance = inst.id;
    te_out.quad = gl_PrimitiveID;
    gl_Position = u_view_projection * vec4(position, 1.0);

#ifdef CAPTURE
    uint k = atomicAdd(count, 1u);
    if (k < capacity) {
        captured[k].position = vec4(position, 1.0);
        captured[k].normal = vec4(normal, 0.0);
        captured[k].coord = vec4(u, v, gl_TessLevelInner[0], gl_TessLevelInner[1]);
        captured[k].outer = vec4(gl_TessLevelOuter[0], gl_TessLevelOuter[1],
                                 gl_TessLevelOuter[2], gl_TessLevelOuter[3]);
        captured[k].ids = ivec4(inst.id, gl_PrimitiveID, tile, 0);
    }
#endif
}
