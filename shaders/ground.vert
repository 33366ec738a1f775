#version 430 core
// The ground: one square at y = 0, u_half metres either side of u_centre (world x, z), made
// from gl_VertexID as a triangle strip of 4 vertices (no vertex buffer).
// Defines accepted: none.

uniform mat4 u_view_projection;
uniform vec2 u_centre;
uniform float u_half;

out vec3 v_position;  // world

void main() {
    vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1)) * 2.0 - 1.0;
    vec3 p = vec3(u_centre.x + u_half * corner.x, 0.0, u_centre.y + u_half * corner.y);
    v_position = p;
    gl_Position = u_view_projection * vec4(p, 1.0);
}
