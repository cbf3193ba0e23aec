"""Host/kernel struct layout: one source of truth, checked on the device."""
import numpy as np
import pyopencl as cl
import pytest

from volrender import layout


def test_committed_header_is_current():
    assert layout.header_path().read_text() == layout.c_header(), \
        "cl/structs.h is stale: run `python -m volrender.layout`"


@pytest.mark.parametrize("name", sorted(layout.STRUCTS))
def test_device_agrees_on_sizes_and_offsets(cl_device, name):
    fields = [f for f, _ in layout.STRUCTS[name]]
    body = "\n".join(
        f"    out[{i + 1}] = (int)((__private char*)&s.{f} - (__private char*)&s);"
        for i, f in enumerate(fields))
    src = f'#include "structs.h"\n__kernel void probe(__global int* out) {{\n' \
          f"    {name} s;\n    out[0] = (int)sizeof({name});\n{body}\n}}\n"
    prg = cl_device.build(src, what=f"layout probe {name}")
    out = np.zeros(len(fields) + 1, np.int32)
    buf = cl.Buffer(cl_device.context, cl.mem_flags.WRITE_ONLY, out.nbytes)
    prg.probe(cl_device.queue, (1,), None, buf)
    cl.enqueue_copy(cl_device.queue, out, buf)
    dt = layout.dtype(name)
    assert out[0] == dt.itemsize
    assert list(out[1:]) == [dt.fields[f][1] for f in fields]


def test_record_rejects_unknown_field():
    with pytest.raises(KeyError):
        layout.record("Camera", fov=1.0)


def test_implicit_padding_is_refused(monkeypatch):
    monkeypatch.setitem(layout.STRUCTS, "Bad", [("a", "float"), ("b", "float4")])
    with pytest.raises(ValueError, match="padding"):
        layout.dtype("Bad")
