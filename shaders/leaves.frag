#version 430 core
// Leaf shading: the family's procedural leaf texture (alpha-tested, neutral detail) times the
// cloud's colour, sun with some light through the leaf from behind, sky ambient. Real geometry writes the final colour with fog; pass 1 of
// the impostor (IMPOSTOR) writes the linear lit colour and, in alpha, where the leaf lies
// between the front (0) and the back (1) of the cloud's bounding sphere along the view
// direction: alpha = (s + r) / (2 r) for the signed distance s to the billboard plane (the
// plane through the centre facing the camera, s > 0 away from it). Empty texels keep the
// clear value -1.
// Defines accepted: IMPOSTOR.

in Leaf {
    vec3 position;
    vec3 normal;
    vec2 st;
    flat vec3 tint;  // the cloud's linear colour (white in pass 1: the billboard tints)
} fs_in;

layout(location = 0) out vec4 o_color;

uniform sampler2D u_leaf;  // sRGB-encoded RGBA8: neutral leaf detail; alpha: the leaf
uniform vec3 u_sun;
uniform vec3 u_sky;
#ifdef IMPOSTOR
uniform vec3 u_forward;   // view direction (unit)
uniform float u_radius;   // bounding radius of the unit cloud
#else
uniform vec3 u_camera;
uniform float u_fog;
#endif

vec3 to_linear(vec3 c) { return pow(c, vec3(2.2)); }
vec3 to_srgb(vec3 c) { return pow(clamp(c, 0.0, 1.0), vec3(1.0 / 2.2)); }

void main() {
    vec4 tex = texture(u_leaf, fs_in.st);
    if (tex.a < 0.5) {
        discard;
    }
#ifdef IMPOSTOR
    vec3 view = -u_forward;
#else
    vec3 view = normalize(u_camera - fs_in.position);
#endif
    vec3 n = normalize(fs_in.normal);
    if (dot(n, view) < 0.0) {
        n = -n;  // cards are double sided
    }
    vec3 albedo = to_linear(tex.rgb) * fs_in.tint;
    float front = max(dot(n, u_sun), 0.0);
    float through = 0.35 * max(-dot(n, u_sun), 0.0);
    vec3 ambient = mix(vec3(0.22, 0.24, 0.16), u_sky, 0.5 + 0.5 * n.y);
    vec3 lit = albedo * (vec3(1.2, 1.15, 1.0) * (front + through) + 0.6 * ambient);
#ifdef IMPOSTOR
    float s = dot(fs_in.position, u_forward);
    o_color = vec4(lit, (s + u_radius) / (2.0 * u_radius));
#else
    float fog = 1.0 - exp(-u_fog * distance(u_camera, fs_in.position));
    o_color = vec4(to_srgb(mix(lit, u_sky, fog)), 1.0);
#endif
}
