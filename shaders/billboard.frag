#version 430 core
// Pass 2 of the 2.5D impostors: the cloud's tile of the pass-1 atlas on the billboard, tinted
// by the cloud's colour (pass 1 shades the neutral texture; lighting is linear in the albedo,
// so tinting afterwards is exact). Empty texels (alpha < 0) are discarded; elsewhere alpha
// gives the leaf's signed distance s from the billboard plane, and the fragment's depth is
// that of the point at s behind (or before) the plane along the pixel's own view ray, so
// billboards depth-test against the branches and against each other as the leaves would.
// Defines accepted: none.

in Billboard {
    vec3 position;
    vec2 st;
    flat float reach;
    flat vec3 tint;
} fs_in;

layout(location = 0) out vec4 o_color;

uniform sampler2D u_impostor;  // RGBA32F: linear lit colour, alpha = (s + r) / (2 r) or -1
uniform mat4 u_view_projection;
uniform vec3 u_camera;
uniform vec3 u_forward;
uniform vec3 u_sky;
uniform float u_fog;

vec3 to_srgb(vec3 c) { return pow(clamp(c, 0.0, 1.0), vec3(1.0 / 2.2)); }

void main() {
    vec4 texel = texture(u_impostor, fs_in.st);
    if (texel.a < 0.0) {
        discard;
    }
    float s = (2.0 * texel.a - 1.0) * fs_in.reach;  // metres along the view direction
    vec3 ray = normalize(fs_in.position - u_camera);
    vec3 p = fs_in.position + ray * (s / dot(ray, u_forward));
    vec4 clip = u_view_projection * vec4(p, 1.0);
    float ndc = clamp(clip.z / clip.w, -1.0, 1.0);
    gl_FragDepth = 0.5 * (gl_DepthRange.diff * ndc + gl_DepthRange.near + gl_DepthRange.far);
    float fog = 1.0 - exp(-u_fog * distance(u_camera, p));
    o_color = vec4(to_srgb(mix(texel.rgb * fs_in.tint, u_sky, fog)), 1.0);
}
