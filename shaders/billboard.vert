#version 430 core
// Pass 2 of the 2.5D impostors (paper 6): one camera-facing billboard per leaf cloud, all in
// one instanced draw (a triangle strip of 4 vertices made from gl_VertexID, no vertex
// buffer). The billboard lies in the plane through the cloud's centre spanned by the camera's
// right and up vectors, half size = diameter * the model's bounding radius, so it covers the
// pass-1 picture of the cloud's model at the cloud's heading exactly: its tile of the atlas
// (column: heading, row: model, u_tiles of them). The centre is the cloud's bone applied to
// its rest point (wind).
// A cloud larger on screen than u_near_pixels is left out (its real leaf cards are drawn
// instead, worker.render.foliage.near_clouds): its four vertices go outside the clip volume.
// Defines accepted: CAPTURE (write every cloud's centre and diameter to a storage buffer).

struct Cloud {
    vec4 rest_size;  // xyz: rest point in the piece's model space (world if bone < 0); w: diameter
    ivec4 bone;      // x: palette entry, -1 for none; y: atlas tile; z: model
    vec4 tint;       // rgb: linear colour
    vec4 turn;       // x: yaw (radians about +y); y: the model's bounding radius
};
layout(std430, binding = 1) readonly buffer Palette { mat4 bones[]; };
layout(std430, binding = 4) readonly buffer Clouds { Cloud clouds[]; };
#ifdef CAPTURE
layout(std430, binding = 3) writeonly buffer Capture { vec4 captured[]; };
#endif

uniform mat4 u_view_projection;
uniform vec3 u_right;
uniform vec3 u_up;
uniform ivec2 u_tiles;  // atlas columns (headings) and rows (models)
uniform vec3 u_camera;
uniform vec3 u_forward;
uniform float u_focal;        // pixels per metre at one metre's depth; 0: no cloud left out
uniform float u_near_pixels;  // on-screen size above which a cloud is left out

out Billboard {
    vec3 position;       // world, on the billboard plane
    vec2 st;             // into the pass-1 atlas
    flat float reach;    // diameter * bounding radius: metres from the centre to the sphere
    flat vec3 tint;
} vs_out;

void main() {
    vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1)) * 2.0 - 1.0;
    Cloud c = clouds[gl_InstanceID];
    vec3 centre = c.bone.x >= 0 ? (bones[c.bone.x] * vec4(c.rest_size.xyz, 1.0)).xyz
                                : c.rest_size.xyz;
    float half_size = c.rest_size.w * c.turn.y;
    float depth = dot(centre - u_camera, u_forward);
    if (u_focal > 0.0 && 2.0 * half_size * u_focal > u_near_pixels * depth) {
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);  // outside the clip volume: nothing drawn
        return;
    }
    vec3 p = centre + half_size * (corner.x * u_right + corner.y * u_up);
    vec2 tile = vec2(float(c.bone.y % u_tiles.x), float(c.bone.y / u_tiles.x));
    vs_out.position = p;
    vs_out.st = (tile + 0.5 * corner + 0.5) / vec2(u_tiles);
    vs_out.reach = half_size;
    vs_out.tint = c.tint.rgb;
    gl_Position = u_view_projection * vec4(p, 1.0);
#ifdef CAPTURE
    if (gl_VertexID == 0) {
        captured[gl_InstanceID] = vec4(centre, c.rest_size.w);
    }
#endif
}
