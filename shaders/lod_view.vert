#version 330
uniform mat4 view_proj;
in vec3 position;
in vec3 normal;
in vec3 tint;
in vec2 st;
in float textured;
out vec3 v_normal;
out vec3 v_tint;
out vec2 v_st;
out float v_textured;
void main() {
    gl_Position = view_proj * vec4(position, 1.0);
    v_normal = normal;
    v_tint = tint;
    v_st = st;
    v_textured = textured;
}
