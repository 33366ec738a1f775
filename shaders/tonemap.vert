#version 430 core
// The tone-map pass: one triangle covering the screen, made from gl_VertexID.
// Defines accepted: none.

void main() {
    vec2 p = vec2(float((gl_VertexID & 1) * 4 - 1), float((gl_VertexID >> 1) * 4 - 1));
    gl_Position = vec4(p, 0.0, 1.0);
}
