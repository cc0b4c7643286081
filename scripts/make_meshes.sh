#!/usr/bin/env bash
# Regenerate the tetrahedral test meshes under data/meshes/ from their upstream
# sources. NOT part of the normal build: the generated files are committed.
#
# Usage: scripts/make_meshes.sh [--large]
#
#   --large   also build a finer armadillo (full-resolution surface, ~26k surface
#             vertices) into build/meshes/ (not committed; too big for the repo).
#
# Sources (see NOTICE):
#   * Armadillo: data/meshes/armadillo.off from CGAL's data tarball, Debian package
#     libcgal-demo (/usr/share/doc/libcgal-dev/data.tar.gz). Originally from the
#     Stanford 3D Scanning Repository.
#   * Bunny: npm package bunny@1.0.1 (Mikola Lysenko, "Public Domain"), a closed
#     1839-vertex Stanford bunny. (CGAL's bunny00.off is also closed but has 37706
#     vertices; it is not used.)
#
# Tools (Debian packages): tetgen, libcgal-dev (+ g++, for a small edge-collapse
# simplifier compiled on the fly), nodejs + npm, python3 (standard library only).
#
# Pipeline per mesh:
#   raw surface (OFF) -> [armadillo: CGAL edge-collapse to ARM_SURF_VERTS vertices]
#   -> check closed/manifold/consistently oriented, orient outward, normalise
#      (largest bounding-box extent = 1 m, x/z centred on the bbox centre, min y = 0)
#   -> <name>_surface.off -> tetgen -pq1.414zY -> <name>.node / <name>.ele
#
# Output conventions: 0-based indices (tetgen -z), 4-node tets, no attributes,
# no boundary markers. Every tet has det([x1-x0, x2-x0, x3-x0]) > 0 (checked below).
set -euo pipefail
cd "$(dirname "$0")/.."

LARGE=0
for arg in "$@"; do
  case "$arg" in
    --large) LARGE=1 ;;
    -h|--help) sed -n '2,28p' "$0"; exit 0 ;;
    *) echo "make_meshes.sh: unknown argument '$arg'" >&2; exit 2 ;;
  esac
done

OUT=data/meshes
BUILD=build/meshes
WORK=$BUILD/work
CGAL_DATA=/usr/share/doc/libcgal-dev/data.tar.gz   # libcgal-demo (Debian)
ARMADILLO_SHA256=6f7f3ca1abc506569466b72f2f59d49493a284e7376d7a7e23c08115ec8cec4e
BUNNY_NPM=bunny@1.0.1
BUNNY_TGZ_SHA1=86383da45ab7a99571a5a572b7be0e3564815f9e
ARM_SURF_VERTS=${ARM_SURF_VERTS:-5000}   # surface vertices of the committed armadillo
TETGEN_FLAGS=-pq1.414zY
MAX_GZ_BYTES=$((1024 * 1024))             # per committed mesh (node + ele + surface)

for tool in tetgen node npm python3 g++ tar gzip sha256sum sha1sum; do
  command -v "$tool" >/dev/null || { echo "make_meshes.sh: missing tool '$tool'" >&2; exit 1; }
done
[[ -f $CGAL_DATA ]] || { echo "make_meshes.sh: $CGAL_DATA not found (apt-get install libcgal-demo)" >&2; exit 1; }
[[ -f /usr/include/CGAL/Surface_mesh_simplification/edge_collapse.h ]] ||
  { echo "make_meshes.sh: CGAL headers not found (apt-get install libcgal-dev)" >&2; exit 1; }

mkdir -p "$OUT" "$WORK"

# ---------------------------------------------------------------- sources
echo "== extracting armadillo.off from $CGAL_DATA"
tar -xzf "$CGAL_DATA" -C "$WORK" --strip-components=2 data/meshes/armadillo.off
mv "$WORK/armadillo.off" "$WORK/armadillo_raw.off"
echo "$ARMADILLO_SHA256  $WORK/armadillo_raw.off" | sha256sum -c --quiet -

echo "== fetching npm $BUNNY_NPM"
if [[ ! -f $WORK/bunny-1.0.1.tgz ]]; then
  (cd "$WORK" && npm pack "$BUNNY_NPM" --silent >/dev/null)
fi
echo "$BUNNY_TGZ_SHA1  $WORK/bunny-1.0.1.tgz" | sha1sum -c --quiet -
rm -rf "$WORK/package"
tar -xzf "$WORK/bunny-1.0.1.tgz" -C "$WORK"
node -e '
  const b = require(require("path").resolve(process.argv[1]));
  const lines = ["OFF", b.positions.length + " " + b.cells.length + " 0"];
  for (const p of b.positions) lines.push(p.join(" "));
  for (const c of b.cells) lines.push(c.length + " " + c.join(" "));
  require("fs").writeFileSync(process.argv[2], lines.join("\n") + "\n");
' "$WORK/package" "$WORK/bunny_raw.off"

# ---------------------------------------------------------------- simplifier
cat > "$WORK/simplify.cpp.new" <<'CPP'
// Edge-collapse simplification of a closed triangle mesh (CGAL, Lindstrom-Turk).
#include <CGAL/Simple_cartesian.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/Polygon_mesh_processing/IO/polygon_mesh_io.h>
#include <CGAL/Surface_mesh_simplification/edge_collapse.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/Count_stop_predicate.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/LindstromTurk_cost.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/LindstromTurk_placement.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/Bounded_normal_change_placement.h>
#include <cstdlib>
#include <fstream>
#include <iostream>
typedef CGAL::Simple_cartesian<double> K;
typedef CGAL::Surface_mesh<K::Point_3> Mesh;
namespace SMS = CGAL::Surface_mesh_simplification;
int main(int argc, char** argv) {
  if (argc != 4) { std::cerr << "usage: simplify in.off out.off target_vertices\n"; return 2; }
  Mesh m;
  if (!CGAL::IO::read_polygon_mesh(argv[1], m) || !CGAL::is_triangle_mesh(m) || !CGAL::is_closed(m)) {
    std::cerr << "simplify: input is not a closed triangle mesh\n"; return 1; }
  const std::size_t nv = std::strtoul(argv[3], nullptr, 10);
  SMS::Count_stop_predicate<Mesh> stop(3 * nv - 6);  // closed genus-0: E = 3V - 6
  SMS::LindstromTurk_cost<Mesh> cost;
  SMS::Bounded_normal_change_placement<SMS::LindstromTurk_placement<Mesh>> placement;
  SMS::edge_collapse(m, stop, CGAL::parameters::get_cost(cost).get_placement(placement));
  m.collect_garbage();
  std::ofstream out(argv[2]);
  out.precision(17);
  if (!CGAL::IO::write_OFF(out, m)) return 1;
  std::cerr << "simplify: " << m.number_of_vertices() << " vertices, " << m.number_of_faces() << " faces\n";
  return 0;
}
CPP
if cmp -s "$WORK/simplify.cpp.new" "$WORK/simplify.cpp"; then
  rm "$WORK/simplify.cpp.new"
else
  mv "$WORK/simplify.cpp.new" "$WORK/simplify.cpp"
fi

# ---------------------------------------------------------------- helpers
# normalize IN.off OUT.off : validate, orient outward, rescale, write OFF.
normalize() {
  python3 - "$1" "$2" <<'PY'
import sys
from collections import Counter
src, dst = sys.argv[1], sys.argv[2]
tok = []
with open(src) as f:
    for line in f:
        tok += line.split('#', 1)[0].split()
if tok[0] != 'OFF':
    sys.exit(f'{src}: not an OFF file')
nv, nf = int(tok[1]), int(tok[2])
i = 4
V = [[float(t) for t in tok[i + 3 * k:i + 3 * k + 3]] for k in range(nv)]
i += 3 * nv
F = []
for _ in range(nf):
    n = int(tok[i])
    if n != 3:
        sys.exit(f'{src}: non-triangle face')
    F.append([int(t) for t in tok[i + 1:i + 4]])
    i += 4
# closed, manifold (every edge in exactly 2 faces), consistently oriented
und = Counter(frozenset((f[a], f[(a + 1) % 3])) for f in F for a in range(3))
dire = Counter((f[a], f[(a + 1) % 3]) for f in F for a in range(3))
if any(c != 2 for c in und.values()):
    sys.exit(f'{src}: surface is not closed/2-manifold')
if any(c != 1 for c in dire.values()):
    sys.exit(f'{src}: faces are not consistently oriented')
used = sorted({v for f in F for v in f})
if len(used) != nv:
    sys.exit(f'{src}: unreferenced vertices')
euler = nv - len(und) + nf
# outward orientation: enclosed signed volume must be positive
def det3(a, b, c):
    return (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
            + a[2] * (b[0] * c[1] - b[1] * c[0]))
vol = sum(det3(V[a], V[b], V[c]) for a, b, c in F) / 6.0
if vol < 0:
    F = [[a, c, b] for a, b, c in F]
lo = [min(v[k] for v in V) for k in range(3)]
hi = [max(v[k] for v in V) for k in range(3)]
s = 1.0 / max(hi[k] - lo[k] for k in range(3))
shift = [0.5 * (lo[0] + hi[0]), lo[1], 0.5 * (lo[2] + hi[2])]
def fmt(x):
    t = '%.9f' % x
    return '0.000000000' if t == '-0.000000000' else t
with open(dst, 'w') as f:
    f.write(f'OFF\n{nv} {nf} 0\n')
    for v in V:
        f.write(' '.join(fmt((v[k] - shift[k]) * s) for k in range(3)) + '\n')
    for a, b, c in F:
        f.write(f'3 {a} {b} {c}\n')
ext = [(hi[k] - lo[k]) * s for k in range(3)]
print(f'  {dst}: {nv} vertices, {nf} triangles, Euler characteristic {euler}, '
      f'{"flipped to outward, " if vol < 0 else ""}scale {s:.6g}, '
      f'extent x/y/z = {ext[0]:.4f} {ext[1]:.4f} {ext[2]:.4f} m')
PY
}

# check BASE : read BASE.node/BASE.ele, report counts, index base, orientation.
check_tets() {
  python3 - "$1" <<'PY'
import sys
base = sys.argv[1]
def rows(path):
    with open(path) as f:
        for line in f:
            r = line.split('#', 1)[0].split()
            if r:
                yield r
it = rows(base + '.node')
n, dim, nattr, nmark = map(int, next(it))
assert dim == 3
P, first = {}, None
for _ in range(n):
    r = next(it)
    if first is None:
        first = int(r[0])
    P[int(r[0])] = [float(x) for x in r[1:4]]
it = rows(base + '.ele')
m, npt, eattr = map(int, next(it))
pos = neg = 0
vmin = float('inf')
for _ in range(m):
    r = next(it)
    a, b, c, d = (P[int(x)] for x in r[1:5])
    u = [b[k] - a[k] for k in range(3)]
    v = [c[k] - a[k] for k in range(3)]
    w = [d[k] - a[k] for k in range(3)]
    det = (u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
           + u[2] * (v[0] * w[1] - v[1] * w[0]))
    pos += det > 0
    neg += det <= 0
    vmin = min(vmin, abs(det) / 6)
print(f'  {base}: {n} vertices, {m} tets ({npt} nodes/tet), first index {first}, '
      f'det>0: {pos}, det<=0: {neg}, min |volume| {vmin:.3g} m^3')
if neg:
    sys.exit(f'{base}: unexpected non-positive tet orientation')
PY
}

# tetmesh NAME SURFACE_OFF DESTDIR : run tetgen, keep only .node/.ele.
tetmesh() {
  local name=$1 surf=$2 dest=$3
  cp "$surf" "$WORK/$name.off"
  if ! (cd "$WORK" && rm -f "$name".1.* && tetgen "$TETGEN_FLAGS" "$name.off" >"$name.tetgen.log" 2>&1); then
    cat "$WORK/$name.tetgen.log" >&2
    echo "make_meshes.sh: tetgen failed on $name" >&2
    exit 1
  fi
  mv "$WORK/$name.1.node" "$dest/$name.node"
  mv "$WORK/$name.1.ele" "$dest/$name.ele"
  rm -f "$WORK/$name".1.*
  check_tets "$dest/$name"
}

gzsize() { local t=0 f; for f in "$@"; do t=$((t + $(gzip -c "$f" | wc -c))); done; echo "$t"; }

# ---------------------------------------------------------------- bunny
echo "== bunny"
normalize "$WORK/bunny_raw.off" "$OUT/bunny_surface.off"
tetmesh bunny "$OUT/bunny_surface.off" "$OUT"

# ---------------------------------------------------------------- armadillo
echo "== armadillo (surface simplified to $ARM_SURF_VERTS vertices)"
if [[ ! -x $WORK/simplify || $WORK/simplify.cpp -nt $WORK/simplify ]]; then
  echo "  compiling CGAL edge-collapse simplifier ..."
  g++ -O2 -std=c++17 -DNDEBUG "$WORK/simplify.cpp" -o "$WORK/simplify"
fi
"$WORK/simplify" "$WORK/armadillo_raw.off" "$WORK/armadillo_simplified.off" "$ARM_SURF_VERTS"
normalize "$WORK/armadillo_simplified.off" "$OUT/armadillo_surface.off"
tetmesh armadillo "$OUT/armadillo_surface.off" "$OUT"

if [[ $LARGE == 1 ]]; then
  echo "== armadillo_large (full-resolution surface, into $BUILD)"
  normalize "$WORK/armadillo_raw.off" "$BUILD/armadillo_large_surface.off"
  tetmesh armadillo_large "$BUILD/armadillo_large_surface.off" "$BUILD"
fi

# ---------------------------------------------------------------- sizes
echo "== gzip-compressed sizes (bytes)"
status=0
for name in bunny armadillo; do
  set -- "$OUT/$name.node" "$OUT/$name.ele" "$OUT/${name}_surface.off"
  total=$(gzsize "$@")
  for f in "$@"; do printf '  %-34s %9d raw %8d gz\n' "$f" "$(wc -c <"$f")" "$(gzsize "$f")"; done
  printf '  %-34s %18d gz total\n' "$name set" "$total"
  if ((total >= MAX_GZ_BYTES)); then
    echo "  ERROR: $name set exceeds 1 MiB compressed; lower ARM_SURF_VERTS" >&2
    status=1
  fi
done
if [[ $LARGE == 1 ]]; then
  for f in "$BUILD"/armadillo_large.node "$BUILD"/armadillo_large.ele "$BUILD"/armadillo_large_surface.off; do
    printf '  %-34s %9d raw %8d gz\n' "$f" "$(wc -c <"$f")" "$(gzsize "$f")"
  done
fi
exit "$status"
