// The GI raster passes' vertices (gi_gbuffer.vert, gi_shadow.vert): world-space triangles in a
// storage buffer, pulled by gl_VertexIndex (non-indexed draw).
struct GiVertex { vec4 position; vec4 normal; vec4 albedo; };
layout(std430, set = 0, binding = 0) readonly buffer Vertices { GiVertex verts[]; };
