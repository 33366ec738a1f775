#version 430 core
// The leaf-cloud model (paper 6): leaf cards of a ball of unit diameter. Two uses:
//  - real geometry: every foliage instance draws the whole cloud, scaled by its diameter, at
//    its centre (its bone applied to its rest point, so it follows the wind);
//  - IMPOSTOR (pass 1): the one cloud in model space, through an orthographic camera looking
//    along the main camera's view direction (the cloud is never rotated, so model directions
//    are world directions and the lighting is the world's).
// Defines accepted: IMPOSTOR.

layout(location = 0) in vec3 in_position;
layout(location = 1) in vec3 in_normal;
layout(location = 2) in vec2 in_st;

#ifndef IMPOSTOR
struct Cloud {
    vec4 rest_size;  // xyz: rest point in the piece's model space (world if bone < 0); w: diameter
    ivec4 bone;      // x: palette entry the cloud follows, -1 for none
};
layout(std430, binding = 1) readonly buffer Palette { mat4 bones[]; };
layout(std430, binding = 4) readonly buffer Clouds { Cloud clouds[]; };
#endif

uniform mat4 u_view_projection;

out Leaf {
    vec3 position;  // world (model space in pass 1)
    vec3 normal;
    vec2 st;
} vs_out;

void main() {
#ifdef IMPOSTOR
    vec3 p = in_position;
#else
    Cloud c = clouds[gl_InstanceID];
    vec3 centre = c.bone.x >= 0 ? (bones[c.bone.x] * vec4(c.rest_size.xyz, 1.0)).xyz
                                : c.rest_size.xyz;
    vec3 p = centre + c.rest_size.w * in_position;
#endif
    vs_out.position = p;
    vs_out.normal = in_normal;
    vs_out.st = in_st;
    gl_Position = u_view_projection * vec4(p, 1.0);
}
