#version 430 core
// Sky gradient: the fog colour at and below the horizon (so the fogged ground meets it without
// a seam), deepening to the zenith colour with the view ray's elevation.
// Defines accepted: none.

in vec2 v_ndc;

layout(location = 0) out vec4 o_color;

uniform vec3 u_right;    // camera basis, world, unit
uniform vec3 u_up;
uniform vec3 u_forward;
uniform vec2 u_tan_half; // tan of half the horizontal and vertical fields of view
uniform vec3 u_sky;      // linear, at the horizon
uniform vec3 u_zenith;   // linear

vec3 to_srgb(vec3 c) { return pow(clamp(c, 0.0, 1.0), vec3(1.0 / 2.2)); }

void main() {
    vec3 ray = normalize(u_forward + v_ndc.x * u_tan_half.x * u_right
                         + v_ndc.y * u_tan_half.y * u_up);
    float t = pow(clamp(ray.y, 0.0, 1.0), 0.55);
    o_color = vec4(to_srgb(mix(u_sky, u_zenith, t)), 1.0);
}
