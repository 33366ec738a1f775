#version 430 core
// The leaf-cloud models (paper 6): leaf cards in a ball of unit diameter. Two uses:
//  - real geometry: every foliage instance of one model (one draw call per model, the
//    clouds' indices in u_first.. of the Order buffer) draws the whole cloud, turned about +y
//    by its yaw, scaled by its diameter, at its centre (its bone applied to its rest point,
//    so it follows the wind), with its colour;
//  - IMPOSTOR (pass 1): one model in its own frame turned by each of the u_steps headings
//    (instance i: yaw 2 pi i / u_steps), through an orthographic camera looking along the
//    main camera's view direction, each heading into its tile of the picture atlas (column
//    i, row u_row of u_steps x u_rows tiles). Turned, model directions are world directions,
//    so the lighting is the world's.
// Defines accepted: IMPOSTOR.

layout(location = 0) in vec3 in_position;
layout(location = 1) in vec3 in_normal;
layout(location = 2) in vec2 in_st;

#ifdef IMPOSTOR
uniform int u_steps;  // headings per model: atlas columns
uniform int u_rows;   // models: atlas rows
uniform int u_row;    // this model's row
#else
struct Cloud {
    vec4 rest_size;  // xyz: rest point in the piece's model space (world if bone < 0); w: diameter
    ivec4 bone;      // x: palette entry the cloud follows, -1 for none; y: atlas tile; z: model
    vec4 tint;       // rgb: linear colour
    vec4 turn;       // x: yaw (radians about +y); y: the model's bounding radius
};
layout(std430, binding = 1) readonly buffer Palette { mat4 bones[]; };
layout(std430, binding = 4) readonly buffer Clouds { Cloud clouds[]; };
layout(std430, binding = 5) readonly buffer Order { int order[]; };
uniform int u_first;  // this model's first entry in Order
#endif

uniform mat4 u_view_projection;

out Leaf {
    vec3 position;  // world (the turned model's space in pass 1)
    vec3 normal;
    vec2 st;
    flat vec3 tint;
} vs_out;

vec3 turn(vec3 v, float yaw) {
    float c = cos(yaw), s = sin(yaw);
    return vec3(c * v.x + s * v.z, v.y, -s * v.x + c * v.z);
}

void main() {
#ifdef IMPOSTOR
    float yaw = 6.283185307179586 * float(gl_InstanceID) / float(u_steps);
    vec3 p = turn(in_position, yaw);
    vs_out.tint = vec3(1.0);  // tinted per cloud on the billboard
#else
    Cloud c = clouds[order[u_first + gl_InstanceID]];
    float yaw = c.turn.x;
    vec3 centre = c.bone.x >= 0 ? (bones[c.bone.x] * vec4(c.rest_size.xyz, 1.0)).xyz
                                : c.rest_size.xyz;
    vec3 p = centre + c.rest_size.w * turn(in_position, yaw);
    vs_out.tint = c.tint.rgb;
#endif
    vs_out.position = p;
    vs_out.normal = turn(in_normal, yaw);
    vs_out.st = in_st;
    gl_Position = u_view_projection * vec4(p, 1.0);
#ifdef IMPOSTOR
    // the ortho picture spans [-1, 1]: squeeze it into this heading's tile of the atlas
    vec2 tile = vec2(float(gl_InstanceID), float(u_row));
    vec2 tiles = vec2(float(u_steps), float(u_rows));
    gl_Position.xy = (gl_Position.xy + 1.0 + 2.0 * tile) / tiles - 1.0;
#endif
}
