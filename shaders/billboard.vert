#version 430 core
// Pass 2 of the 2.5D impostors (paper 6): one camera-facing billboard per leaf cloud, all in
// one instanced draw (a triangle strip of 4 vertices made from gl_VertexID, no vertex
// buffer). The billboard lies in the plane through the cloud's centre spanned by the camera's
// right and up vectors, half size = diameter * u_radius, so it covers the cloud's picture from
// pass 1 exactly. The centre is the cloud's bone applied to its rest point (wind).
// Defines accepted: CAPTURE (write every cloud's centre and diameter to a storage buffer).

struct Cloud {
    vec4 rest_size;  // xyz: rest point in the piece's model space (world if bone < 0); w: diameter
    ivec4 bone;      // x: palette entry, -1 for none
};
layout(std430, binding = 1) readonly buffer Palette { mat4 bones[]; };
layout(std430, binding = 4) readonly buffer Clouds { Cloud clouds[]; };
#ifdef CAPTURE
layout(std430, binding = 3) writeonly buffer Capture { vec4 captured[]; };
#endif

uniform mat4 u_view_projection;
uniform vec3 u_right;
uniform vec3 u_up;
uniform float u_radius;  // bounding radius of the unit cloud

out Billboard {
    vec3 position;    // world, on the billboard plane
    vec2 st;          // into the pass-1 picture
    flat float size;  // the cloud's diameter
} vs_out;

void main() {
    vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1)) * 2.0 - 1.0;
    Cloud c = clouds[gl_InstanceID];
    vec3 centre = c.bone.x >= 0 ? (bones[c.bone.x] * vec4(c.rest_size.xyz, 1.0)).xyz
                                : c.rest_size.xyz;
    float half_size = c.rest_size.w * u_radius;
    vec3 p = centre + half_size * (corner.x * u_right + corner.y * u_up);
    vs_out.position = p;
    vs_out.st = 0.5 * corner + 0.5;
    vs_out.size = c.rest_size.w;
    gl_Position = u_view_projection * vec4(p, 1.0);
#ifdef CAPTURE
    if (gl_VertexID == 0) {
        captured[gl_InstanceID] = vec4(centre, c.rest_size.w);
    }
#endif
}
