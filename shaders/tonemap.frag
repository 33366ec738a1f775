#version 430 core
// The staged frame's filmic tone map: the resolved half-float frame holds colours in the
// shaders' gamma-2.2 encoding but unclamped; decoded, scaled by the exposure, mapped by the
// ACES filmic fit (Narkowicz 2015) and encoded for the 8-bit preview.
// Defines accepted: none.

layout(location = 0) out vec4 o_color;

uniform sampler2D u_frame;
uniform float u_exposure;

vec3 aces(vec3 x) {
    return clamp((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0);
}

void main() {
    vec3 c = texelFetch(u_frame, ivec2(gl_FragCoord.xy), 0).rgb;
    vec3 lin = pow(max(c, 0.0), vec3(2.2));
    o_color = vec4(pow(aces(u_exposure * lin), vec3(1.0 / 2.2)), 1.0);
}
