#version 430 core
// The sky: one triangle covering the screen, made from gl_VertexID (no vertex buffer).
// Defines accepted: none.

out vec2 v_ndc;

void main() {
    vec2 p = vec2(float((gl_VertexID & 1) * 4 - 1), float((gl_VertexID >> 1) * 4 - 1));
    v_ndc = p;
    gl_Position = vec4(p, 1.0, 1.0);
}
