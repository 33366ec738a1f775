#version 430 core
// Level of detail for quad patches (paper 4.4). An edge's level depends only on the camera
// distance of the edge's midpoint, computed symmetrically in its two vertices, so the two
// patches that share an edge (within a piece or across a rim) choose the same level and no
// crack opens. The inner levels come from the distance of the quad's centre. Patches wholly
// outside the view frustum are dropped here, before any tessellation work.
// Defines accepted: none.

layout(vertices = 4) out;

in Vertex {
    vec3 position;
    vec3 normal;
    vec2 st;
    int slot;
} tc_in[];

out ControlPoint {
    vec3 position;
    vec3 normal;
    vec2 st;
    int slot;
} tc_out[];

uniform vec3 u_camera;     // world
uniform float u_tess_max;  // cap of the level, >= 1
uniform float u_lod_near;  // metres: closer than this, the level is u_tess_max
uniform float u_lod_half;  // metres over which the level halves; <= 0 means no falloff
uniform float u_alpha;     // Phong shape factor (bounds how far the surface bulges)
uniform bool u_cull;       // drop patches wholly outside the view frustum
uniform vec4 u_frustum[6]; // world planes (unit normal, offset), inside where dot >= 0

// Whether the patch lies wholly outside one frustum plane. The bilinear patch stays within r
// of its centre c (r: the farthest corner), and Phong tessellation moves a point by at most
// alpha times its distance to a corner (< 2 r), so the surface lies in a sphere of radius
// r (1 + 2 alpha) about c.
bool outside(vec3 p0, vec3 p1, vec3 p2, vec3 p3) {
    vec3 c = 0.25 * (p0 + p1 + p2 + p3);
    float r = max(max(distance(c, p0), distance(c, p1)), max(distance(c, p2), distance(c, p3)));
    r *= 1.0 + 2.0 * u_alpha;
    for (int k = 0; k < 6; ++k) {
        if (dot(u_frustum[k].xyz, c) + u_frustum[k].w < -r) {
            return true;
        }
    }
    return false;
}

// Exponential falloff with distance, capped by the maximum level.
float level(vec3 p) {
    float d = max(distance(u_camera, p) - u_lod_near, 0.0);
    float f = u_lod_half > 0.0 ? exp2(-d / u_lod_half) : 1.0;
    return clamp(u_tess_max * f, 1.0, u_tess_max);
}

void main() {
    tc_out[gl_InvocationID].position = tc_in[gl_InvocationID].position;
    tc_out[gl_InvocationID].normal = tc_in[gl_InvocationID].normal;
    tc_out[gl_InvocationID].st = tc_in[gl_InvocationID].st;
    tc_out[gl_InvocationID].slot = tc_in[gl_InvocationID].slot;
    if (gl_InvocationID == 0) {
        // Corners sit at tess coords 0:(0,0) 1:(0,1) 2:(1,1) 3:(1,0) (the quad winding
        // a_i, b_i, b_i+1, a_i+1 and its st). Outer level k belongs to the edge
        // 0: u = 0, 1: v = 0, 2: u = 1, 3: v = 1.
        vec3 p0 = tc_in[0].position;
        vec3 p1 = tc_in[1].position;
        vec3 p2 = tc_in[2].position;
        vec3 p3 = tc_in[3].position;
        gl_TessLevelOuter[0] = level(0.5 * (p0 + p1));
        gl_TessLevelOuter[1] = level(0.5 * (p0 + p3));
        gl_TessLevelOuter[2] = level(0.5 * (p3 + p2));
        gl_TessLevelOuter[3] = level(0.5 * (p1 + p2));
        float inner = level(0.25 * (p0 + p1 + p2 + p3));
        gl_TessLevelInner[0] = inner;
        gl_TessLevelInner[1] = inner;
        if (u_cull && outside(p0, p1, p2, p3)) {
            // an outer level of 0 discards the patch; it is off screen, so its edges with
            // drawn neighbours are too
            gl_TessLevelOuter[0] = 0.0;
        }
    }
}
