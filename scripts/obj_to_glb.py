#!/usr/bin/env python3
"""Converts a Wavefront OBJ (with its MTL) into a binary glTF that coherent loads.

    python3 scripts/obj_to_glb.py IN.obj OUT.glb

One glTF mesh primitive per OBJ material (faces keep their order within it), flat normals
(each face's own; its corners are not shared with other faces, so hard edges stay hard), the
material's diffuse colour `Kd` as the base colour factor. Polygons are split into fans;
texture coordinates, `vn` normals, smoothing groups, lines and points are ignored. Only the
Python standard library is needed. Used to try coherent on public OBJ models such as the
Sibenik cathedral (docs/measurements.md), which are never committed.
"""

import json
import math
import os
import struct
import sys


def read_mtl(path):
    """Material name -> diffuse colour (Kd), from an MTL file; missing file: no colours."""
    colours = {}
    name = None
    try:
        with open(path, encoding="latin-1") as f:
            for line in f:
                parts = line.split()
                if not parts:
                    continue
                if parts[0] == "newmtl" and len(parts) > 1:
                    name = " ".join(parts[1:])
                    colours.setdefault(name, (0.8, 0.8, 0.8))
                elif parts[0] == "Kd" and name is not None and len(parts) >= 4:
                    colours[name] = tuple(min(max(float(x), 0.0), 1.0) for x in parts[1:4])
    except OSError as e:
        print(f"warning: {path}: {e}; materials drawn grey", file=sys.stderr)
    return colours


def read_obj(path):
    """Positions, material libraries and, per material, its triangles (position indices)."""
    positions = []
    libraries = []
    groups = {}
    current = "default"
    with open(path, encoding="latin-1") as f:
        for number, line in enumerate(f, 1):
            parts = line.split()
            if not parts:
                continue
            key = parts[0]
            if key == "v":
                if len(parts) < 4:
                    raise ValueError(f"{path}:{number}: a vertex needs three coordinates")
                p = tuple(float(x) for x in parts[1:4])
                if not all(math.isfinite(c) for c in p):
                    raise ValueError(f"{path}:{number}: a vertex coordinate is not finite")
                positions.append(p)
            elif key == "f":
                corners = []
                for token in parts[1:]:
                    i = int(token.split("/")[0])
                    i = i - 1 if i > 0 else len(positions) + i
                    if not 0 <= i < len(positions):
                        raise ValueError(f"{path}:{number}: face index {token} out of range")
                    corners.append(i)
                tris = groups.setdefault(current, [])
                for k in range(1, len(corners) - 1):
                    tris.append((corners[0], corners[k], corners[k + 1]))
            elif key == "usemtl":
                current = " ".join(parts[1:]) or "default"
            elif key == "mtllib":
                libraries.append(" ".join(parts[1:]))
    return positions, libraries, groups


def flat(positions, tris):
    """Per-corner positions and flat normals of `tris` (degenerate faces dropped)."""
    pos = []
    nrm = []
    for a, b, c in tris:
        pa, pb, pc = positions[a], positions[b], positions[c]
        u = [pb[i] - pa[i] for i in range(3)]
        v = [pc[i] - pa[i] for i in range(3)]
        n = (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])
        length = math.sqrt(sum(x * x for x in n))
        if length == 0.0 or not math.isfinite(length):
            continue
        n = tuple(x / length for x in n)
        pos.extend((pa, pb, pc))
        nrm.extend((n, n, n))
    return pos, nrm


def convert(obj_path, glb_path):
    positions, libraries, groups = read_obj(obj_path)
    colours = {}
    for lib in libraries:
        colours.update(read_mtl(os.path.join(os.path.dirname(obj_path), lib)))
    blob = bytearray()
    doc = {
        "asset": {"version": "2.0", "generator": "coherent scripts/obj_to_glb.py"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": []}],
        "materials": [],
        "accessors": [],
        "bufferViews": [],
        "buffers": [],
    }
    triangles = 0
    for name, tris in groups.items():
        pos, nrm = flat(positions, tris)
        if not pos:
            continue
        triangles += len(pos) // 3
        accessors = []
        for data, with_bounds in ((pos, True), (nrm, False)):
            offset = len(blob)
            for p in data:
                blob += struct.pack("<3f", *p)
            doc["bufferViews"].append(
                {"buffer": 0, "byteOffset": offset, "byteLength": len(blob) - offset,
                 "target": 34962}
            )
            acc = {"bufferView": len(doc["bufferViews"]) - 1, "componentType": 5126,
                   "count": len(data), "type": "VEC3"}
            if with_bounds:
                acc["min"] = [min(p[i] for p in data) for i in range(3)]
                acc["max"] = [max(p[i] for p in data) for i in range(3)]
            doc["accessors"].append(acc)
            accessors.append(len(doc["accessors"]) - 1)
        r, g, b = colours.get(name, (0.8, 0.8, 0.8))
        doc["materials"].append(
            {"name": name, "pbrMetallicRoughness": {"baseColorFactor": [r, g, b, 1.0],
                                                    "metallicFactor": 0.0}}
        )
        doc["meshes"][0]["primitives"].append(
            {"attributes": {"POSITION": accessors[0], "NORMAL": accessors[1]},
             "material": len(doc["materials"]) - 1}
        )
    if not triangles:
        raise ValueError(f"{obj_path}: no faces")
    doc["buffers"].append({"byteLength": len(blob)})
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    blob += b"\0" * (-len(blob) % 4)
    with open(glb_path, "wb") as out:
        out.write(struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(text) + 8 + len(blob)))
        out.write(struct.pack("<I4s", len(text), b"JSON") + text)
        out.write(struct.pack("<I4s", len(blob), b"BIN\0") + bytes(blob))
    return triangles, len(doc["materials"])


def main():
    if len(sys.argv) != 3:
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        sys.exit(2)
    try:
        triangles, materials = convert(sys.argv[1], sys.argv[2])
    except (OSError, ValueError) as e:
        print(f"obj_to_glb: {e}", file=sys.stderr)
        sys.exit(1)
    print(f"{sys.argv[2]}: {triangles} triangles, {materials} materials")


if __name__ == "__main__":
    main()
