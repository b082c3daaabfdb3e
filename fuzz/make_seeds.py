#!/usr/bin/env python3
"""Makes the DEM seeds of fuzz/corpus/dem and fuzz/corpus/dem_forced: tiny cuts of the real files
in ../shared/data/dem (GeoTIFF tags kept), plus ImageMagick re-encodings of such cuts (tiles,
big-endian, deflate, LZW, PackBits, EXR). Run from the repository root; needs `convert`
(ImageMagick). The seeds are committed; this documents how they were made.

Each seed's first byte is the fuzz target's selector: for `dem`, the file name (0 .tif, 1 .png,
2 .exr, 3 N47E008.hgt, 4 .asc, 5 .dem); for `dem_forced`, the forced format in
`DemFormat::ALL` order (0 geotiff, 1 png, 2 terrain-rgb, 3 terrarium, 4 exr, 5 hgt, 6 asc).
"""
import os
import struct
import subprocess
import sys
import tempfile

DATA = os.path.join("..", "shared", "data", "dem")
TYPE_SIZE = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 6: 1, 7: 1, 8: 2, 9: 4, 10: 8, 11: 4, 12: 8, 16: 8}


def read_tiff(path):
    """Tags {tag: (type, count, raw value bytes)} of the first IFD and the uncompressed raster."""
    b = open(path, "rb").read()
    assert b[:4] == b"II*\0", path
    (ifd,) = struct.unpack_from("<I", b, 4)
    (n,) = struct.unpack_from("<H", b, ifd)
    tags = {}
    for k in range(n):
        tag, typ, count, value = struct.unpack_from("<HHII", b, ifd + 2 + 12 * k)
        size = TYPE_SIZE[typ] * count
        raw = b[ifd + 10 + 12 * k: ifd + 14 + 12 * k][:size] if size <= 4 else b[value: value + size]
        tags[tag] = (typ, count, raw)

    def ints(tag):
        typ, count, raw = tags[tag]
        fmt = {3: "H", 4: "I"}[typ]
        return list(struct.unpack("<%d%s" % (count, fmt), raw))

    assert ints(259) == [1], "uncompressed only"
    width, height, bps = ints(256)[0], ints(257)[0], ints(258)[0] // 8
    if 273 in tags:
        raster = b"".join(b[o: o + c] for o, c in zip(ints(273), ints(279)))
    else:
        # Tiles, row by row of tiles, each tw x th samples (edge tiles padded).
        tw, th = ints(322)[0], ints(323)[0]
        across = -(-width // tw)
        tiles = [b[o: o + c] for o, c in zip(ints(324), ints(325))]
        rows = []
        for y in range(height):
            row = b""
            for tx in range(across):
                tile = tiles[(y // th) * across + tx]
                at = (y % th) * tw * bps
                row += tile[at: at + tw * bps]
            rows.append(row[: width * bps])
        raster = b"".join(rows)
        for tag in (322, 323, 324, 325):
            del tags[tag]
    return tags, raster, width, height, bps


def write_tiff(tags, raster, path):
    """A little-endian TIFF, one strip, with `tags` (raw values) plus the strip's offset."""
    entries = sorted(tags.items())
    header = 8
    ifd_size = 2 + 12 * len(entries) + 4
    out_of_line = b""
    body = []
    data_at = header + ifd_size
    for tag, (typ, count, raw) in entries:
        if len(raw) > 4:
            off = data_at + len(out_of_line)
            out_of_line += raw + (b"\0" if len(raw) % 2 else b"")
            body.append(struct.pack("<HHII", tag, typ, count, off))
        else:
            body.append(struct.pack("<HHI", tag, typ, count) + raw.ljust(4, b"\0"))
    strip_at = data_at + len(out_of_line)
    # Patch the strip offset (a LONG, inline).
    body = [
        struct.pack("<HHII", 273, 4, 1, strip_at) if struct.unpack_from("<H", e)[0] == 273 else e for e in body
    ]
    ifd = struct.pack("<H", len(entries)) + b"".join(body) + struct.pack("<I", 0)
    open(path, "wb").write(b"II*\0" + struct.pack("<I", header) + ifd + out_of_line + raster)


def cut_tiff(src, x, y, w, h):
    tags, raster, width, height, bps = read_tiff(src)
    rows = [raster[((y + r) * width + x) * bps: ((y + r) * width + x + w) * bps] for r in range(h)]
    data = b"".join(rows)
    tags = dict(tags)
    tags[256] = (4, 1, struct.pack("<I", w))
    tags[257] = (4, 1, struct.pack("<I", h))
    tags[273] = (4, 1, struct.pack("<I", 0))
    tags[278] = (4, 1, struct.pack("<I", h))
    tags[279] = (4, 1, struct.pack("<I", len(data)))
    return tags, data


def main():
    out = {"dem": os.path.join("fuzz", "corpus", "dem"), "dem_forced": os.path.join("fuzz", "corpus", "dem_forced")}
    for d in out.values():
        os.makedirs(d, exist_ok=True)
    tmp = tempfile.mkdtemp()
    files = {}  # name -> (bytes, dem selector, dem_forced selector)

    for name, src, at in [("tif-zurich-i16", "zurich_25m_i16.tif", (200, 180)), ("tif-lidar-f32", "lidar_1m_f32.tif", (100, 100))]:
        tags, data = cut_tiff(os.path.join(DATA, src), at[0], at[1], 6, 5)
        p = os.path.join(tmp, name + ".tif")
        write_tiff(tags, data, p)
        files[name] = (open(p, "rb").read(), 0, 0)
        if name == "tif-zurich-i16":
            # .hgt: the same kind of heights, big-endian i16, a 4 x 4 tile.
            t2, d2 = cut_tiff(os.path.join(DATA, src), at[0], at[1], 4, 4)
            vals = struct.unpack("<16h", d2)
            files["hgt"] = (struct.pack(">16h", *vals[:15], -32768), 3, 5)

    def magick(name, args, ext, sel):
        p = os.path.join(tmp, name + "." + ext)
        subprocess.run(["convert"] + args + [p], check=True)
        files[name] = (open(p, "rb").read(), sel[0], sel[1])

    etopo = os.path.join(DATA, "etopo20_world.tif")
    magick("tif-etopo-tiled-zip", [etopo, "-crop", "8x6+500+200", "+repage", "-define", "quantum:format=floating-point",
                                    "-depth", "32", "-compress", "zip", "-define", "tiff:tile-geometry=4x4"], "tif", (0, 0))
    zurich = os.path.join(DATA, "zurich_25m_i16.tif")
    magick("tif-zurich-be-lzw", [zurich, "-crop", "6x5+10+10", "+repage", "-endian", "MSB", "-compress", "lzw"], "tif", (0, 0))
    magick("tif-zurich-packbits", [zurich, "-crop", "6x5+30+30", "+repage", "-compress", "rle"], "tif", (0, 0))
    magick("png-terrarium", [os.path.join(DATA, "terrarium.png"), "-crop", "5x4+100+100", "+repage",
                             "-define", "png:color-type=2"], "png", (1, 3))
    magick("png-fuji-rgba", [os.path.join(DATA, "fuji_terrain_rgb.png"), "-crop", "5x4+200+200", "+repage",
                             "-define", "png:color-type=6"], "png", (1, 2))
    magick("png-gray16", [zurich, "-crop", "6x5+50+50", "+repage", "-depth", "16", "-colorspace", "gray"], "png", (1, 1))
    magick("exr-lidar", [os.path.join(DATA, "lidar_1m_f32.tif"), "-crop", "4x3+100+100", "+repage", "-colorspace", "gray",
                         "-compress", "zip"], "exr", (2, 4))
    magick("exr-lidar-raw", [os.path.join(DATA, "lidar_1m_f32.tif"), "-crop", "3x2+10+10", "+repage",
                             "-compress", "none"], "exr", (2, 4))

    asc = open(os.path.join(DATA, "hugo_site_nodata.asc"), "rb").read().decode().splitlines()
    header, body = asc[:6], asc[6:]
    cut = [" ".join(line.split()[29:34]) for line in body[2:6]]
    header = [("ncols 5" if l.lower().startswith("ncols") else "nrows 4" if l.lower().startswith("nrows") else l) for l in header]
    files["asc-hugo"] = (("\n".join(header + cut) + "\n").encode(), 4, 6)

    for name, (data, dem_sel, forced_sel) in files.items():
        open(os.path.join(out["dem"], "seed-" + name), "wb").write(bytes([dem_sel]) + data)
        open(os.path.join(out["dem_forced"], "seed-" + name), "wb").write(bytes([forced_sel]) + data)
    for name in sorted(files):
        print(name, len(files[name][0]))


if __name__ == "__main__":
    sys.exit(main())
