#version 430 core
// Bark shading: the quad's tile (a slice of the texture array chosen per instance and quad,
// paper 5.1), a sun and a sky, distance fog.
// Defines accepted: ID_OUTPUT (second colour output: tile, instance id, patch, 1); STAGED (sun
// shadows from a depth map with 3x3 bilinear PCF, a stronger sky fill, and the colour left
// unclamped for the tone-map pass: see worker.render.staging).

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
#ifdef STAGED
uniform sampler2DShadow u_shadow;  // the sun's depth map, compare mode on
uniform mat4 u_light_vp;           // world -> the sun's clip space
uniform float u_shadow_texel;      // metres per shadow texel
// unclamped: the tone map compresses highlights (the encoding is only a storage format here)
vec3 to_srgb(vec3 c) { return pow(max(c, 0.0), vec3(1.0 / 2.2)); }

// fraction of the sun that reaches p (1: lit); the sample point moves along the normal by a
// texel or two (more at grazing angles), so a surface never shadows itself
float sunlight(vec3 p, vec3 n) {
    float grazing = 1.0 - max(dot(n, u_sun), 0.0);
    vec4 clip = u_light_vp * vec4(p + n * u_shadow_texel * (0.5 + 1.5 * grazing), 1.0);
    vec3 q = clip.xyz / clip.w * 0.5 + 0.5;
    if (any(lessThan(q, vec3(0.0))) || any(greaterThan(q, vec3(1.0)))) {
        return 1.0;  // outside the map: nothing casts there
    }
    vec2 texel = 1.0 / vec2(textureSize(u_shadow, 0));
    float sum = 0.0;
    for (int y = -1; y <= 1; ++y) {
        for (int x = -1; x <= 1; ++x) {
            sum += texture(u_shadow, vec3(q.xy + vec2(x, y) * texel, q.z));
        }
    }
    return sum / 9.0;
}
#else
vec3 to_srgb(vec3 c) { return pow(clamp(c, 0.0, 1.0), vec3(1.0 / 2.2)); }
#endif

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
#ifdef STAGED
    float sun = sunlight(fs_in.position, n);
    diffuse *= sun;
    spec *= sun;
    // the sky fills every face with at least 0.18 of the albedo: none goes black
    vec3 lit = albedo * (vec3(1.35, 1.27, 1.13) * diffuse + max(0.7 * ambient, vec3(0.18))) + spec;
#else
    vec3 lit = albedo * (vec3(1.25, 1.18, 1.05) * diffuse + 0.55 * ambient) + spec;
#endif
    float fog = 1.0 - exp(-u_fog * distance(u_camera, fs_in.position));
    o_color = vec4(to_srgb(mix(lit, u_sky, fog)), 1.0);
#ifdef ID_OUTPUT
    o_ids = ivec4(fs_in.tile, fs_in.instance, fs_in.quad, 1);
#endif
}
