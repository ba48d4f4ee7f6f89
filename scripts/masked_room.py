# Writes masked_room.gltf (or the path given): a 12x12 green floor, a 4x4 white quad at y=2 whose texture is a 4x4 checker of
# holes (MASK 0.5, nearest, clamp), four walls and a ceiling (so the file is an enclosed room), and a
# KHR_lights_punctual spot light at y=4 pointing down.
import struct, zlib, base64, json, sys
def png(w, h, rgba):
    raw = b''.join(b'\x00' + bytes(rgba[y*w*4:(y+1)*w*4]) for y in range(h))
    def chunk(t, d): return struct.pack('>I', len(d)) + t + d + struct.pack('>I', zlib.crc32(t + d) & 0xffffffff)
    return b'\x89PNG\r\n\x1a\n' + chunk(b'IHDR', struct.pack('>IIBBBBB', w, h, 8, 6, 0, 0, 0)) + chunk(b'IDAT', zlib.compress(raw)) + chunk(b'IEND', b'')
rgba = []
for k in range(16):
    i, j = k % 4, k // 4
    rgba += [255, 255, 255, 0 if (i + j) % 2 else 255]
bin_ = bytearray(); views = []; accessors = []; meshes = []
def view(b):
    while len(bin_) % 4: bin_.append(0)
    views.append({"buffer": 0, "byteOffset": len(bin_), "byteLength": len(b)}); bin_.extend(b); return len(views) - 1
def acc(v, ct, ty, n, **kw):
    a = {"bufferView": v, "componentType": ct, "type": ty, "count": n}; a.update(kw); accessors.append(a); return len(accessors) - 1
def quad(corners, normal, material):
    p = acc(view(b''.join(struct.pack('<3f', *c) for c in corners)), 5126, "VEC3", 4,
            min=[min(c[k] for c in corners) for k in range(3)], max=[max(c[k] for c in corners) for k in range(3)])
    n = acc(view(struct.pack('<3f', *normal) * 4), 5126, "VEC3", 4)
    uv = acc(view(b''.join(struct.pack('<2f', *t) for t in [(0, 0), (0, 1), (1, 1), (1, 0)])), 5126, "VEC2", 4)
    i = acc(view(struct.pack('<6H', 0, 1, 2, 0, 2, 3)), 5123, "SCALAR", 6)
    meshes.append({"primitives": [{"attributes": {"POSITION": p, "NORMAL": n, "TEXCOORD_0": uv}, "indices": i, "material": material}]})
    return len(meshes) - 1
S, H = 6.0, 5.0
ms = [quad([(-S, 0, -S), (-S, 0, S), (S, 0, S), (S, 0, -S)], (0, 1, 0), 0),
      quad([(-2, 2, -2), (-2, 2, 2), (2, 2, 2), (2, 2, -2)], (0, 1, 0), 1),
      quad([(-S, H, -S), (S, H, -S), (S, H, S), (-S, H, S)], (0, -1, 0), 2),
      quad([(-S, 0, -S), (S, 0, -S), (S, H, -S), (-S, H, -S)], (0, 0, 1), 2),
      quad([(S, 0, S), (-S, 0, S), (-S, H, S), (S, H, S)], (0, 0, -1), 2),
      quad([(-S, 0, S), (-S, 0, -S), (-S, H, -S), (-S, H, S)], (1, 0, 0), 2),
      quad([(S, 0, -S), (S, 0, S), (S, H, S), (S, H, -S)], (-1, 0, 0), 2)]
nodes = [{"mesh": m} for m in ms]
nodes.append({"translation": [0, 4, 0], "rotation": [-0.7071068, 0, 0, 0.7071068], "extensions": {"KHR_lights_punctual": {"light": 0}}})
doc = {"asset": {"version": "2.0"}, "extensionsUsed": ["KHR_lights_punctual"],
       "extensions": {"KHR_lights_punctual": {"lights": [{"type": "spot", "intensity": 100, "spot": {"outerConeAngle": 1.2}}]}},
       "scene": 0, "scenes": [{"nodes": list(range(len(nodes)))}], "nodes": nodes, "meshes": meshes,
       "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.1, 0.8, 0.1, 1]}},
                     {"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}, "alphaMode": "MASK", "alphaCutoff": 0.5},
                     {"pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.8, 0.8, 1]}}],
       "images": [{"uri": "data:image/png;base64," + base64.b64encode(png(4, 4, rgba)).decode()}],
       "samplers": [{"magFilter": 9728, "minFilter": 9728, "wrapS": 33071, "wrapT": 33071}],
       "textures": [{"source": 0, "sampler": 0}],
       "accessors": accessors, "bufferViews": views,
       "buffers": [{"byteLength": len(bin_), "uri": "data:application/octet-stream;base64," + base64.b64encode(bytes(bin_)).decode()}]}
open(sys.argv[1] if len(sys.argv) > 1 else 'masked_room.gltf', 'w').write(json.dumps(doc))
