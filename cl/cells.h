/* Support cells (volrender/cells.py builds them, cl/build_cells.cl has the bounds): a
   world-space grid over the clip box, cells of edge `cell`, grouped in bricks of
   VR_CELL_BRICK^3 cells. bricks[b] = (code, bound bits): code >= 0 is the block of the
   brick's cells in `cells`; VR_CELL_OUTSIDE / VR_CELL_INSIDE: the whole brick lies outside
   the glass (F >= bound > tau) or inside it (F <= bound < -tau). cells[block * B^3 + local]
   likewise: code >= 0 is the cell's list, lists[code] = (start, count, start, core count)
   into `entries`: (sphere, key bits) of every sphere that can matter in the cell, by
   ascending key, a lower bound of the sphere's distance from any point of the cell
   (cl/build_cells.cl, build_walk_fill). The spheres that can be the nearest (the core)
   come first, and sdf.h's passes stop at the first key beyond m or m + k. A ray on one side of the
   surface crosses skippable cells of its side without evaluating the field (DDA to the exit
   of the cell or brick). Include from sdf.h (SdfScene holds the grid). */
#ifndef VR_CELLS_H
#define VR_CELLS_H

typedef struct {
    int code;          /* >= 0: list index; VR_CELL_OUTSIDE / VR_CELL_INSIDE: skippable */
    float bound;       /* skippable: lower (outside) or upper (inside) bound of F */
    float3 lo, hi;     /* the cell's or the brick's box */
} SdfCell;

inline SdfCell sdf_cell(const SdfScene* sc, float3 x)
{
#if VR_STATS
    ++sc->stats->y;
#endif
    float3 g = floor((x - sc->grid_lo) * sc->inv_cell);
    int3 q = convert_int3(clamp(g, (float3)(0.0f), convert_float3(sc->dims - 1)));
    int3 b = q / VR_CELL_BRICK;
    int2 e = sc->bricks[(b.z * sc->bdims.y + b.y) * sc->bdims.x + b.x];
    SdfCell c;
    if (e.x < 0) {
        c.code = e.x;
        c.bound = as_float(e.y);
        c.lo = sc->grid_lo + convert_float3(b * VR_CELL_BRICK) * sc->cell;
        c.hi = sc->grid_lo + convert_float3(b * VR_CELL_BRICK + VR_CELL_BRICK) * sc->cell;
        return c;
    }
    int3 l = q - b * VR_CELL_BRICK;
    int2 v = sc->cells[e.x * (VR_CELL_BRICK * VR_CELL_BRICK * VR_CELL_BRICK) +
                       (l.z * VR_CELL_BRICK + l.y) * VR_CELL_BRICK + l.x];
    c.code = v.x;
    c.bound = as_float(v.y);
    c.lo = sc->grid_lo + convert_float3(q) * sc->cell;
    c.hi = sc->grid_lo + convert_float3(q + 1) * sc->cell;
    return c;
}

/* Does a ray on `side` (+1 outside glass, -1 inside) skip this cell? */
inline int sdf_cell_skips(const SdfCell* c, float side)
{
    return c->code == (side > 0.0f ? VR_CELL_OUTSIDE : VR_CELL_INSIDE);
}

/* Ray parameter just past the exit of the cell's box (always beyond t) */
inline float sdf_cell_exit(const SdfScene* sc, const SdfCell* c, float3 o, float3 inv_d, float t)
{
    float3 ta = (c->lo - o) * inv_d, tb = (c->hi - o) * inv_d;   /* NaN on an axis: ignored */
    float3 tf = fmax(ta, tb);
    float te = fmin(fmin(tf.x, tf.y), tf.z);
    return fmax(te, t) + sc->nudge + 4e-7f * fabs(t);
}

#endif
