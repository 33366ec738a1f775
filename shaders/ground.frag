#version 430 core
// Ground shading: a procedural meadow (value-noise patches of grass, dry grass and bare soil
// at 7 m, 0.6 m and 15 cm), lit by the bark's sun and hemisphere sky with the same distance
// fog, so the ground fades into the horizon's sky colour. Octaves finer than a pixel fade to
// their mean (fwidth) instead of shimmering.
// Defines accepted: STAGED (sun shadows from the depth map, colour unclamped for the tone map;
// see piece.frag), TERRAIN (a mixed forest's terrain: lit by its interpolated normal, bare
// soil and leaf litter on slopes).

in vec3 v_position;
#ifdef TERRAIN
in vec3 v_normal;
#endif

layout(location = 0) out vec4 o_color;

uniform vec3 u_camera;
uniform vec3 u_sun;   // unit, towards the sun
uniform vec3 u_sky;   // linear
uniform float u_fog;  // density per metre

#ifdef STAGED
uniform sampler2DShadow u_shadow;
uniform mat4 u_light_vp;
uniform float u_shadow_texel;
vec3 to_srgb(vec3 c) { return pow(max(c, 0.0), vec3(1.0 / 2.2)); }

float sunlight(vec3 p, vec3 n) {
#ifdef TERRAIN
    // the terrain is smooth: a texel or two up the normal is enough against acne
    float grazing = 1.0 - clamp(dot(n, u_sun), 0.0, 1.0);
    vec4 clip = u_light_vp * vec4(p + n * u_shadow_texel * (1.0 + 1.5 * grazing), 1.0);
#else
    // the ground is flat and faces up: a texel up the normal is enough against acne
    vec4 clip = u_light_vp * vec4(p + vec3(0.0, u_shadow_texel, 0.0), 1.0);
#endif
    vec3 q = clip.xyz / clip.w * 0.5 + 0.5;
    if (any(lessThan(q, vec3(0.0))) || any(greaterThan(q, vec3(1.0)))) {
        return 1.0;
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

float hash(vec2 cell) {
    // integer hash of the lattice cell: the same pattern on every driver
    uvec2 q = uvec2(ivec2(cell) + ivec2(32768)) * uvec2(1597334673u, 3812015801u);
    uint n = (q.x ^ q.y) * 1597334673u;
    return float(n) * (1.0 / 4294967295.0);
}

float value_noise(vec2 p) {
    vec2 i = floor(p);
    vec2 f = fract(p);
    vec2 u = f * f * (3.0 - 2.0 * f);
    return mix(mix(hash(i), hash(i + vec2(1.0, 0.0)), u.x),
               mix(hash(i + vec2(0.0, 1.0)), hash(i + vec2(1.0, 1.0)), u.x), u.y);
}

// three octaves of value noise in [0, 1]; an octave fades to 0.5 once a cell spans a pixel
float fbm(vec2 p) {
    float sum = 0.0;
    float amp = 0.5;
    for (int k = 0; k < 3; ++k) {
        float fade = clamp(1.5 - 2.0 * length(fwidth(p)), 0.0, 1.0);
        sum += amp * mix(0.5, value_noise(p), fade);
        p = p * 2.03 + vec2(11.7, 5.3);
        amp *= 0.5;
    }
    return sum / 0.875;
}

void main() {
    vec2 xz = v_position.xz;
    vec3 grass = vec3(0.075, 0.13, 0.035);
    vec3 dry = vec3(0.17, 0.17, 0.07);
    vec3 soil = vec3(0.14, 0.10, 0.06);
    float patches = fbm(xz / 7.0);
    float bare = fbm(xz / 0.6 + 17.0);
    vec3 albedo = mix(grass, dry, smoothstep(0.5, 0.8, patches));
    albedo = mix(albedo, soil, 0.7 * smoothstep(0.6, 0.8, bare));
#ifdef TERRAIN
    // slopes: the grass thins to soil and litter where the ground tilts past ~15 degrees
    vec3 n = normalize(v_normal);
    albedo = mix(albedo, mix(soil, dry, 0.4), 0.6 * smoothstep(0.95, 0.85, n.y));
    albedo *= 0.75 + 0.5 * fbm(xz / 0.15 + 41.0);
    float diffuse = max(dot(n, u_sun), 0.0);
    vec3 sky = (0.5 + 0.5 * n.y) * u_sky;  // the hemisphere ambient a tilted face sees
#else
    vec3 n = vec3(0.0, 1.0, 0.0);
    albedo *= 0.75 + 0.5 * fbm(xz / 0.15 + 41.0);
    // the normal is +Y: the hemisphere ambient is the sky's colour
    float diffuse = max(u_sun.y, 0.0);
    vec3 sky = u_sky;
#endif
#ifdef STAGED
    diffuse *= sunlight(v_position, n);
    vec3 lit = albedo * (vec3(1.35, 1.27, 1.13) * diffuse + 0.7 * sky);
#else
    vec3 lit = albedo * (vec3(1.25, 1.18, 1.05) * diffuse + 0.55 * sky);
#endif
    float fog = 1.0 - exp(-u_fog * distance(u_camera, v_position));
    o_color = vec4(to_srgb(mix(lit, u_sky, fog)), 1.0);
}
