// Shared by every particle stage: grid parameters, SPH kernels, minimum-image wrapping, and the
// live count (shared/live.wgsl). Mirrored in f64 by src/sim/reference/common.rs (same names).
//!include shared/live.wgsl

const PI: f32 = 3.14159265358979;

// Linear thread index of a 2D dispatch (x up to MAX_GROUPS_X workgroups, then rows of y) with
// `wg` threads per workgroup; `linear_id` for the WG_PARTICLES-thread workgroups of the particle
// stages.
fn thread_index(gid: vec3<u32>, nwg: vec3<u32>, wg: u32) -> u32 {
    return gid.x + gid.y * nwg.x * wg;
}
fn linear_id(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return thread_index(gid, nwg, WG_PARTICLES);
}

// PCG-RXS-M-XS hash (Jarzynski & Olano 2020), a well-mixed u32 -> u32; u32 arithmetic wraps.
// Mirror: sim::noise::pcg_hash.
fn pcg_hash(v: u32) -> u32 {
    let state = v * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// x + g in f32 without the bias of rounding. x + g rounds by the fraction of an ulp that g
// leaves, which is the same for every x of one binade: an increment below half an ulp of x (3e-5
// K at 300 K) is dropped, every time, and one increment given to many particles is rounded the
// same way for all of them. Either adds up (the entrainment's gain of a clear particle; the
// conservative smoothing's flux into a particle whose neighbours differ little from it; the
// forcing's heating of the surface layer, docs/PHYSICS.md "Heat budget"). A g of fewer than
// 65536 ulps of x (the fraction then keeps 8 bits) is added as a whole number of ulps, rounded
// up with the probability of its fraction, drawn from `key` (a hash of the state, so a run and
// its resume agree); a sum that would leave the binade is a plain one. It works on the bits,
// not by recovering the rounding error with float sums, which a driver may simplify away
// (lavapipe does). Positive x only. Mirror: the exact sum.
fn add_unbiased(x: f32, g: f32, key: u32) -> f32 {
    let bits = bitcast<u32>(x);
    let ulp = bitcast<f32>(bits + 1u) - x;
    let q = g / ulp;
    if (x <= 0.0 || !(abs(q) < 65536.0)) { return x + g; }
    let u = f32(pcg_hash(key) >> 8u) * (1.0 / 16777216.0);
    let r = u32(max(i32(bits) + i32(floor(q + u)), 0));
    // across a power of two the ulp changes: a plain sum there
    if ((r >> 23u) != (bits >> 23u)) { return x + g; }
    return bitcast<f32>(r);
}

// The key of `add_unbiased` for a particle at p: a hash of its position's bits and `salt` (0,
// or a hash of the values it adds to), so a run and its resume draw the same.
fn state_key(p: vec3<f32>, salt: u32) -> u32 {
    let b = bitcast<vec3<u32>>(p);
    return pcg_hash(b.x ^ pcg_hash(b.y ^ pcg_hash(b.z ^ salt)));
}

// Uniform grid over the domain; x and z may be periodic (minimum image), y is walled.
struct GridParams {
    domain_min: vec3<f32>,
    // (the particle count is `live.count`, shared/live.wgsl: it changes on the GPU)
    _pad0: u32,
    domain_size: vec3<f32>,
    n_boundary: u32,
    cell_size: vec3<f32>,
    num_cells: u32,
    dims: vec3<u32>,
    // bit 0: x periodic, bit 2: z periodic
    periodic: u32,
    // Each cell is cut into x_slices slices along x; particles are sorted by (cell, slice) and a
    // cell table has one entry per slice: cell c spans entries c * x_slices .. (c + 1) * x_slices.
    x_slices: u32,
    // radius a neighbour search covers around a particle's current position, measured to the
    // cells as sorted (the largest kernel radius)
    search_radius: f32,
    _pad1: u32,
    _pad2: u32,
}

// Poly6 kernel W(r, h), used for densities and interpolation.
fn poly6(r2: f32, h: f32) -> f32 {
    let h2 = h * h;
    if (r2 >= h2) { return 0.0; }
    let d = h2 - r2;
    return 315.0 / (64.0 * PI * pow(h, 9.0)) * d * d * d;
}

// Gradient of the spiky kernel with respect to x_i, for x_ij = x_i - x_j with |x_ij| = r.
fn spiky_grad(xij: vec3<f32>, r: f32, h: f32) -> vec3<f32> {
    if (r >= h || r <= 1e-9 * h) { return vec3<f32>(0.0); }
    let d = h - r;
    return (-45.0 / (PI * pow(h, 6.0)) * d * d / r) * xij;
}

// Symmetric kernels for particles of different radii (paper eq. 19).
fn poly6_sym(r2: f32, hi: f32, hj: f32) -> f32 {
    return 0.5 * (poly6(r2, hi) + poly6(r2, hj));
}
fn spiky_grad_sym(xij: vec3<f32>, r: f32, hi: f32, hj: f32) -> vec3<f32> {
    return 0.5 * (spiky_grad(xij, r, hi) + spiky_grad(xij, r, hj));
}

// Minimum-image displacement across periodic faces.
fn min_image(d: vec3<f32>, g: GridParams) -> vec3<f32> {
    var r = d;
    if ((g.periodic & 1u) != 0u) { r.x = r.x - g.domain_size.x * round(r.x / g.domain_size.x); }
    if ((g.periodic & 4u) != 0u) { r.z = r.z - g.domain_size.z * round(r.z / g.domain_size.z); }
    return r;
}

// The periodic image of a grid, for neighbour loops: read from the uniform once per invocation,
// then min_image_by_reciprocal per pair (one multiply instead of a divide; the rounded image is the
// same for every pair closer than half the domain, i.e. every pair within h0: a periodic axis
// holds at least 3 cells of edge >= h0).
struct Image {
    per_x: bool,
    per_z: bool,
    size: vec3<f32>,
    inv: vec3<f32>,
}
fn image_of(g: GridParams) -> Image {
    return Image((g.periodic & 1u) != 0u, (g.periodic & 4u) != 0u, g.domain_size,
        1.0 / g.domain_size);
}
fn min_image_by_reciprocal(d: vec3<f32>, im: Image) -> vec3<f32> {
    var r = d;
    if (im.per_x) { r.x = r.x - im.size.x * round(r.x * im.inv.x); }
    if (im.per_z) { r.z = r.z - im.size.z * round(r.z * im.inv.z); }
    return r;
}

// Integer cell of a position (clamped into the grid).
fn cell_coord(p: vec3<f32>, g: GridParams) -> vec3<i32> {
    let c = vec3<i32>(floor((p - g.domain_min) / g.cell_size));
    return clamp(c, vec3<i32>(0), vec3<i32>(g.dims) - vec3<i32>(1));
}

// n in -1..=d into 0..d, i.e. (n + d) % d there, without the integer division (x86 has no vector
// integer divide: llvmpipe runs one scalar divide per lane)
fn wrap(n: i32, d: i32) -> i32 {
    return select(select(n, n - d, n >= d), n + d, n < 0);
}

// Linear index of cell c + offset, wrapping periodic axes; -1 when outside a walled axis.
fn neighbor_cell(c: vec3<i32>, offset: vec3<i32>, g: GridParams) -> i32 {
    var n = c + offset;
    let d = vec3<i32>(g.dims);
    if ((g.periodic & 1u) != 0u) { n.x = wrap(n.x, d.x); } else if (n.x < 0 || n.x >= d.x) { return -1; }
    if (n.y < 0 || n.y >= d.y) { return -1; }
    if ((g.periodic & 4u) != 0u) { n.z = wrap(n.z, d.z); } else if (n.z < 0 || n.z >= d.z) { return -1; }
    return (n.z * d.y + n.y) * d.x + n.x;
}

// Sort key of a position: its cell's first table entry plus its x slice within the cell.
fn slice_key(p: vec3<f32>, g: GridParams) -> u32 {
    let c = cell_coord(p, g);
    let w = g.cell_size.x / f32(g.x_slices);
    let s = floor((p.x - g.domain_min.x - f32(c.x) * g.cell_size.x) / w);
    let slice = u32(clamp(s, 0.0, f32(g.x_slices - 1u)));
    return u32(neighbor_cell(c, vec3<i32>(0), g)) * g.x_slices + slice;
}

// First cell-table entry of cell c (the table has one entry per x slice).
fn cell_entry(c: u32, g: GridParams) -> u32 {
    return c * g.x_slices;
}

// Table entries [x, y) of the whole cell kc (0..27) of the 27 around cell c, in neighbourhood
// order: offset (kc % 3, kc / 3 % 3, kc / 9) - 1, x fastest; empty (0, 0) outside a walled axis.
fn cell_entries(c: vec3<i32>, kc: u32, g: GridParams) -> vec2<u32> {
    let off = vec3<i32>(i32(kc % 3u) - 1, i32((kc / 3u) % 3u) - 1, i32(kc / 9u) - 1);
    let n = neighbor_cell(c, off, g);
    if (n < 0) { return vec2<u32>(0u); }
    return vec2<u32>(cell_entry(u32(n), g), cell_entry(u32(n) + 1u, g));
}

// Neighbour search by rows. The cells x-1..x+1 of a (y, z) row are consecutive in the linear
// cell index, and within a cell the particles are sorted by x slice (GridParams.x_slices), so a
// row is one run of cell-table entries ordered by x. Each of the 9 rows around the particle is
// clipped to the slices that meet its search sphere (radius R = g.search_radius, h0): a row
// farther than R in (y, z) is skipped, the others span x +- sqrt(R^2 - d_yz^2). That visits
// about 60% of the 27-cell candidates (x_slices = 2). Across a periodic x face a row is two
// segments.
// Returns the table entry ranges [x, y) and [z, w) (empty: equal ends).
fn row_entries(p: vec3<f32>, c: vec3<i32>, dy: i32, dz: i32, g: GridParams) -> vec4<u32> {
    let none = vec4<u32>(0u);
    let d = vec3<i32>(g.dims);
    let ny = c.y + dy;
    if (ny < 0 || ny >= d.y) { return none; }
    var nz = c.z + dz;
    if ((g.periodic & 4u) != 0u) { nz = wrap(nz, d.z); } else if (nz < 0 || nz >= d.z) { return none; }
    // distance from p to the row's slab in y and z (unwrapped neighbour cell: periodic images
    // are adjacent)
    let lo = g.domain_min.yz + vec2<f32>(f32(ny), f32(c.z + dz)) * g.cell_size.yz;
    let q = max(max(lo - p.yz, p.yz - (lo + g.cell_size.yz)), vec2<f32>(0.0));
    let r2 = g.search_radius * g.search_radius - dot(q, q);
    if (r2 <= 0.0) { return none; }
    // a hair wider than the sphere: slices are binned in f32 like the keys
    let ext = sqrt(r2) + 1e-5 * g.cell_size.x;
    let w = g.cell_size.x / f32(g.x_slices);
    let xs = i32(g.x_slices);
    let x = p.x - g.domain_min.x;
    let a = max(i32(floor((x - ext) / w)), (c.x - 1) * xs);
    let b = min(i32(floor((x + ext) / w)), (c.x + 2) * xs - 1);
    return row_span(nz, ny, a, b, g);
}

// Whether the wall particles of cell row ny can be within hm of a particle at height py. They
// are binned into the first and the last y row, the floor's below y = 0 and the ceiling's above
// y = size, at least d / 2 beyond the plane (sim::init::boundary_particles): a particle hm or
// more from the plane has none closer than hm, so its lane skips the row's wall loop with every
// sum unchanged. The particles of the second and the last-but-one row of cells, at least a cell
// (>= h0) away, walked the wall row next to them before and rejected every candidate.
fn wall_reach(ny: i32, py: f32, hm: f32, g: GridParams) -> bool {
    return (ny == 0 && py < hm) || (ny == i32(g.dims.y) - 1 && py > g.domain_size.y - hm);
}

// Offset from a row's entries in the fluid cell table to the same row's in the wall table,
// which holds only the first and the last y row of cells, where every wall particle lies
// (GridParams::wall_entry in grid_params.rs): wall entries = row entries - wall_shift. Only for
// those rows (ny the first or the last); z is the row's unwrapped cell index.
fn wall_shift(ny: i32, z: i32, g: GridParams) -> u32 {
    let d = vec3<i32>(g.dims);
    var nz = z;
    if ((g.periodic & 4u) != 0u) { nz = wrap(nz, d.z); }
    let rows = min(d.y, 2);
    let w = select(0, rows - 1, ny > 0);
    return u32((nz * d.y + ny - (nz * rows + w)) * d.x * i32(g.x_slices));
}

// Table entry ranges of the slices a..=b of row (ny, nz) (slice indices along the whole row,
// a may be < 0 or b past the end on a periodic x axis: then two segments; clipped at x walls).
fn row_span(nz: i32, ny: i32, a: i32, b: i32, g: GridParams) -> vec4<u32> {
    let none = vec4<u32>(0u);
    let nx = i32(g.dims.x) * i32(g.x_slices);
    let base = u32((nz * i32(g.dims.y) + ny) * nx);
    if ((g.periodic & 1u) == 0u) {
        let a0 = max(a, 0);
        let b0 = min(b, nx - 1);
        if (a0 > b0) { return none; }
        return vec4<u32>(base + u32(a0), base + u32(b0 + 1), 0u, 0u);
    }
    if (b - a + 1 >= nx) { return vec4<u32>(base, base + u32(nx), 0u, 0u); }
    if (a < 0) {
        return vec4<u32>(base + u32(a + nx), base + u32(nx), base, base + u32(b + 1));
    }
    if (b >= nx) {
        return vec4<u32>(base + u32(a), base + u32(nx), base, base + u32(b - nx + 1));
    }
    return vec4<u32>(base + u32(a), base + u32(b + 1), 0u, 0u);
}
