#version 330
uniform sampler2D leaf;
uniform vec3 eye;      // towards the camera
uniform float lit;     // 1: sun and sky (a picture to look at); 0: albedo (an impostor)
in vec3 v_normal;
in vec3 v_tint;
in vec2 v_st;
in float v_textured;
layout(location = 0) out vec4 albedo;
layout(location = 1) out vec4 normal_out;
layout(location = 2) out vec4 depth_out;
void main() {
    vec3 base = v_tint;
    if (v_textured > 0.5) {
        vec4 t = texture(leaf, v_st);
        if (t.a < ALPHA_CUT) discard;
        base *= pow(t.rgb, vec3(2.2));
    }
    vec3 n = normalize(v_normal);
    if (dot(n, eye) < 0.0) n = -n;  // double-sided cards face the viewer
    vec3 sun = normalize(vec3(0.4, 0.8, 0.45));
    float light = mix(1.0, 0.35 + 0.65 * max(dot(n, sun), 0.0) + 0.15 * n.y, lit);
    albedo = vec4(pow(base * light, vec3(1.0 / 2.2)), 1.0);
    normal_out = vec4(0.5 + 0.5 * n, 1.0);
    depth_out = vec4(gl_FragCoord.z, 0.0, 0.0, 1.0);
}
