#version 430 core
// Bark shading: the quad's tile (a slice of the texture array chosen per instance and quad,
// paper 5.1), a sun and a sky, distance fog.
// Defines accepted: ID_OUTPUT (second colour output: tile, instance id, patch, 1).

in Surface {
    vec3 position;
    vec3 normal;
    vec2 st;
    flat int tile;
    flat int instance;
    flat int quad;
} fs_in;

layout(location = 0) out vec4 o_color;
#ifdef ID_OUTPUT
layout(location = 1) out ivec4 o_ids;
#endif

uniform sampler2DArray u_tiles;  // sRGB-encoded RGBA8 slices
uniform vec3 u_camera;
uniform vec3 u_sun;              // unit, towards the sun
uniform vec3 u_sky;              // linear colour of the sky (fog and ambient)
uniform float u_fog;             // fog density per metre

vec3 to_linear(vec3 c) { return pow(c, vec3(2.2)); }
vec3 to_srgb(vec3 c) { return pow(clamp(c, 0.0, 1.0), vec3(1.0 / 2.2)); }

void main() {
    vec3 view = normalize(u_camera - fs_in.position);
    vec3 n = normalize(fs_in.normal);
    if (dot(n, view) < 0.0) {
        n = -n;  // open rims show the inside of a tube
    }
    int slice = max(fs_in.tile, 0);
    vec3 albedo = to_linear(texture(u_tiles, vec3(fs_in.st, float(slice))).rgb);
    if (fs_in.tile < 0) {
        albedo = vec3(1.0, 0.0, 1.0);  // a quad without a tile breaks the scene contract
    }
    float diffuse = max(dot(n, u_sun), 0.0);
    // hemisphere ambient: sky above, warm ground bounce below
    vec3 ambient = mix(vec3(0.30, 0.26, 0.20), u_sky, 0.5 + 0.5 * n.y);
    vec3 h = normalize(u_sun + view);
    float spec = 0.06 * pow(max(dot(n, h), 0.0), 24.0) * step(0.0, diffuse);
    vec3 lit = albedo * (vec3(1.25, 1.18, 1.05) * diffuse + 0.55 * ambient) + spec;
    float fog = 1.0 - exp(-u_fog * distance(u_camera, fs_in.position));
    o_color = vec4(to_srgb(mix(lit, u_sky, fog)), 1.0);
#ifdef ID_OUTPUT
    o_ids = ivec4(fs_in.tile, fs_in.instance, fs_in.quad, 1);
#endif
}
