"""The partition tree built on the render device (cl/build_tree.cl), giving exactly the
numpy build's tree (volrender/tree.py with the same float32 keys): the same sphere order,
node ranges and float32 node boxes (tree.float32_boxes). PyOpenCL's radix sort orders
the points once per axis; each level is two kernels and one segmented scan per axis, with
no host round trip. Needs PyOpenCL's Mako-templated algorithms (pyopencl.algorithm)."""
from __future__ import annotations

import functools

import numpy as np

from .tree import Tree, node_ranges, tree_depth


@functools.lru_cache(maxsize=None)
def _primitives(ctx_ptr, context):
    """The radix sort and the split scan for one context (built once)."""
    from pyopencl.algorithm import RadixSort
    from pyopencl.scan import GenericScanKernel
    sort = RadixSort(context, "uint *keys, int *ids", key_expr="keys[i]",
                     sort_arg_names=["keys", "ids"], bits_at_a_time=2)
    # one axis' sorted list split stably into the children's: lefts keep their order at
    # the node's start, rights after its ceil(c/2) lefts (item: lefts so far in the node)
    split = GenericScanKernel(
        context, np.int32,
        arguments="__global const int *src, __global const uchar *is_left, "
                  "__global const int *node_of, __global const int *start, "
                  "__global const int *count, __global int *dst",
        input_expr="is_left[src[i]]",
        scan_expr="across_seg_boundary ? b : (a + b)", neutral="0",
        is_segment_start_expr="i == start[node_of[i] >> 1]",
        output_statement="""
            int par = node_of[i] >> 1, s = start[par], left = (count[par] + 1) / 2;
            int f = is_left[src[i]], lb = item - f;
            dst[s + (f ? lb : left + (i - s) - lb)] = src[i];""")
    return sort, split


def scan_fits(scan, n: int, device) -> bool:
    """Whether a pyopencl scan of n items passes its own check that the second level can
    scan the first level's intervals (it asserts interval size >= interval count, which
    fails for some n on devices with many compute units, e.g. the H200 at n = 10^5)."""
    from pytools import uniform_interval_splitting
    info = scan.first_level_scan_info
    size, count = uniform_interval_splitting(n, info.wg_size * info.k_group_size,
                                             3 * device.device.max_compute_units)
    return size >= count


def padded(n: int, device) -> int:
    """A sort length >= n at which the scan's interval check holds: intervals are about
    n / (3 compute units) long, at most 3 compute units of them."""
    return max(n, (3 * device.device.max_compute_units) ** 2 + 1)


class Unsupported(Exception):
    """pyopencl's scan cannot run at this size on this device: build on the host."""


def build(device, keys, spheres, leaf_size: int, origin=(0.0, 0.0, 0.0)):
    """(tree.Tree, spheres in tree order: float32 (N, 4)), built on `device` (a
    volrender.device.Device). keys: float32 (N, 3) split coordinates; spheres: float32
    (N, 4) centre, radius in the input order, in the frame whose world origin is `origin`
    (the Tree's float32 boxes are in that frame, with no margin)."""
    import pyopencl.array as cla
    n = len(keys)
    depth = tree_depth(n, int(leaf_size))
    ctx, queue = device.context, device.queue
    k = {name: device.kernel("build_tree", {}, name) for name in
         ("tree_keys", "tree_axes", "tree_split", "tree_gather", "tree_leaves", "tree_parents")}
    sort, split = _primitives(ctx.int_ptr, ctx)
    start, count = node_ranges(n, depth)
    d_start = cla.to_device(queue, start.astype(np.int32))
    d_count = cla.to_device(queue, count.astype(np.int32))
    d_keys = cla.to_device(queue, np.ascontiguousarray(np.asarray(keys, np.float32).T))
    if depth and not scan_fits(split, n, device):
        raise Unsupported(f"pyopencl's scan of {n} items on {device.name}")
    g = (max(64, -(-n // 64) * 64),)
    npad = padded(n, device)
    by = []
    for a in range(3):
        # padded keys sort last (0xffffffff: no finite float32 maps there), after the
        # points, so the first n indices are the points' order
        key = cla.empty(queue, npad, np.uint32).fill(np.uint32(0xFFFFFFFF))
        idx = cla.arange(queue, npad, dtype=np.int32)
        k["tree_keys"](queue, g, None, d_keys.data, np.int32(a), key.data, idx.data, np.int32(n))
        (_, sidx), _ = sort(key, idx, key_bits=32, queue=queue)
        by.append(sidx[:n].copy() if npad > n else sidx)
    node_of = cla.empty(queue, n, np.int32).fill(1)
    is_left = cla.empty(queue, n, np.uint8)
    order = cla.empty(queue, n, np.int32) if depth else cla.arange(queue, n, dtype=np.int32)
    axis = cla.empty(queue, max(1, 1 << max(depth - 1, 0)), np.int32)
    for d in range(depth):
        first = 1 << d
        gn = (max(64, -(-first // 64) * 64),)
        k["tree_axes"](queue, gn, None, d_keys.data, np.int32(n), by[0].data, by[1].data,
                      by[2].data, d_start.data, d_count.data, np.int32(first), axis.data)
        last = d == depth - 1
        k["tree_split"](queue, g, None, np.int32(n), np.int32(first), d_start.data,
                       d_count.data, axis.data, by[0].data, by[1].data, by[2].data,
                       node_of.data, is_left.data, order.data, np.int32(last))
        if last:
            break
        for a in range(3):
            moved = cla.empty(queue, n, np.int32)
            split(by[a], is_left, node_of, d_start, d_count, moved, queue=queue)
            by[a] = moved
    d_pts = cla.to_device(queue, np.ascontiguousarray(spheres, np.float32))
    d_sp = cla.empty(queue, (n, 4), np.float32)
    k["tree_gather"](queue, g, None, d_pts.data, order.data, d_sp.data, np.int32(n))
    size = 2 << depth
    lo = cla.empty(queue, (size, 4), np.float32).fill(np.float32(np.inf))
    hi = cla.empty(queue, (size, 4), np.float32).fill(np.float32(-np.inf))
    first = 1 << depth
    k["tree_leaves"](queue, (max(64, -(-first // 64) * 64),), None, d_sp.data, d_start.data,
                    d_count.data, np.int32(first), lo.data, hi.data)
    for d in range(depth - 1, -1, -1):
        first = 1 << d
        k["tree_parents"](queue, (max(64, -(-first // 64) * 64),), None, np.int32(first),
                         lo.data, hi.data)
    tree = Tree(lo=lo.get()[:, :3], hi=hi.get()[:, :3], start=start, count=count, depth=depth,
                leaf_size=int(leaf_size), margin=0.0, n_points=n,
                order=order.get().astype(np.int64), origin=np.asarray(origin, np.float64))
    out = d_sp.get()
    queue.finish()
    return tree, out
