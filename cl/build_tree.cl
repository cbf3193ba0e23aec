/* The partition tree built on the device (volrender/tree_device.py drives it): the same
   median splits as volrender/tree.py's numpy build, level by level. The points are sorted
   once per axis (pyopencl's radix sort, stable); each level takes per node the axis of the
   longest extent of its float32 keys (tree_axes; ties to the lower axis, as np.argmax),
   marks the first ceil(c/2) points along it left (tree_split), and splits each axis'
   sorted list stably into the children's (a segmented scan in tree_device.py). Then the
   spheres in tree order (tree_gather) and the float32 node boxes, leaves (tree_leaves)
   then parents level by level (tree_parents), computed as tree.float32_boxes does. */
#include "common.h"

/* axis a's float32 keys (keys[a n + i]) as uints that sort the same way (-0 and +0
   alike), with the point indices */
__kernel void tree_keys(__global const float* keys, int a, __global uint* key,
                        __global int* idx, int n)
{
    int i = get_global_id(0);
    if (i >= n)
        return;
    uint u = as_uint(keys[a * n + i] + 0.0f);
    key[i] = (u & 0x80000000u) ? ~u : (u | 0x80000000u);
    idx[i] = i;
}

/* axis[j] of node first + j: the longest extent of its keys along the sorted lists */
__kernel void tree_axes(__global const float* keys, int n, __global const int* bx,
                        __global const int* by, __global const int* bz,
                        __global const int* start, __global const int* count, int first,
                        __global int* axis)
{
    int j = get_global_id(0);
    if (j >= first)
        return;
    int node = first + j, c = count[node];
    if (c <= 0) {
        axis[j] = 0;
        return;
    }
    int s = start[node], e = s + c - 1;
    float ex = keys[bx[e]] - keys[bx[s]];
    float ey = keys[n + by[e]] - keys[n + by[s]];
    float ez = keys[2 * n + bz[e]] - keys[2 * n + bz[s]];
    int a = 0;
    float m = ex;
    if (ey > m) { a = 1; m = ey; }
    if (ez > m) { a = 2; }
    axis[j] = a;
}

/* position p of a level: its point goes left when among the first ceil(c/2) of its node
   along the node's axis; node_of[p] becomes the child's; with last, order[p] = the point */
__kernel void tree_split(int n, int first, __global const int* start,
                         __global const int* count, __global const int* axis,
                         __global const int* bx, __global const int* by, __global const int* bz,
                         __global int* node_of, __global uchar* is_left, __global int* order,
                         int last)
{
    int p = get_global_id(0);
    if (p >= n)
        return;
    int node = node_of[p], s = start[node], c = count[node];
    int left = (c + 1) / 2, rel = p - s;
    int a = axis[node - first];
    int id = a == 0 ? bx[p] : (a == 1 ? by[p] : bz[p]);
    is_left[id] = rel < left;
    node_of[p] = 2 * node + (rel >= left);
    if (last)
        order[p] = id;
}

/* spheres in tree order: out[p] = pts[order[p]] */
__kernel void tree_gather(__global const float4* pts, __global const int* order,
                          __global float4* out, int n)
{
    int p = get_global_id(0);
    if (p < n)
        out[p] = pts[order[p]];
}

/* leaf first + j: the box of centre -+ radius over its spheres (float32) */
__kernel void tree_leaves(__global const float4* sp, __global const int* start,
                          __global const int* count, int first, __global float4* lo,
                          __global float4* hi)
{
    int j = get_global_id(0);
    if (j >= first)
        return;
    int node = first + j, s = start[node], c = count[node];
    float3 a = (float3)(INFINITY), b = (float3)(-INFINITY);
    for (int i = s; i < s + c; ++i) {
        float4 q = sp[i];
        a = fmin(a, q.xyz - q.w);
        b = fmax(b, q.xyz + q.w);
    }
    lo[node] = (float4)(a, 0.0f);
    hi[node] = (float4)(b, 0.0f);
}

/* parents first + j of one level: the union of their children's boxes */
__kernel void tree_parents(int first, __global float4* lo, __global float4* hi)
{
    int j = get_global_id(0);
    if (j >= first)
        return;
    int p = first + j;
    lo[p] = fmin(lo[2 * p], lo[2 * p + 1]);
    hi[p] = fmax(hi[2 * p], hi[2 * p + 1]);
}
