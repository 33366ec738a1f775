#version 430 core
// The ground: one square at y = 0 (with UNDER_TERRAIN: at y = u_height, under a mixed
// forest's terrain), u_half metres either side of u_centre (world x, z), made from
// gl_VertexID as a triangle strip of 4 vertices (no vertex buffer); or, with TERRAIN, the
// terrain mesh itself (world points and normals, indexed triangles).
// Defines accepted: TERRAIN, UNDER_TERRAIN.

uniform mat4 u_view_projection;

out vec3 v_position;  // world

#ifdef TERRAIN
layout(location = 0) in vec3 in_position;
layout(location = 1) in vec3 in_normal;
out vec3 v_normal;  // world

void main() {
    v_position = in_position;
    v_normal = in_normal;
    gl_Position = u_view_projection * vec4(in_position, 1.0);
}
#else
uniform vec2 u_centre;
uniform float u_half;
#ifdef UNDER_TERRAIN
uniform float u_height;
#else
const float u_height = 0.0;
#endif

void main() {
    vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1)) * 2.0 - 1.0;
    vec3 p = vec3(u_centre.x + u_half * corner.x, u_height, u_centre.y + u_half * corner.y);
    v_position = p;
    gl_Position = u_view_projection * vec4(p, 1.0);
}
#endif
