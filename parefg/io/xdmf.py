"""``result.xdmf``: the XDMF 3 index of ``result.h5`` for ParaView, grown in place.

A Temporal collection with one Spatial collection per output step, holding a Polyvertex
grid "nodes" and, when there is a contact boundary, a Polyvertex grid "contact"; scalars
are Scalar attributes, 2-vectors Vector attributes, centred on the points.  Every
DataItem points into ``result.h5`` by a relative path.
"""

from __future__ import annotations

import os
import pathlib
import xml.etree.ElementTree as ET

import numpy as np

from parefg.parallel import raise_everywhere

H5_NAME = "result.h5"
XDMF_NAME = "result.xdmf"
# XDMF number types by numpy kind; XDMF calls 1-byte integers Char / UChar (status is int8)
XDMF_NUMBER_TYPES = {"f": "Float", "i": "Int", "u": "UInt"}
XDMF_BYTE_TYPES = {"i": "Char", "u": "UChar", "b": "UChar"}
# result.xdmf around the snapshots, as ElementTree indents the whole document
XDMF_HEAD = (
    '<?xml version="1.0"?>\n<Xdmf Version="3.0">\n  <Domain>\n'
    '    <Grid Name="TimeSeries" GridType="Collection" CollectionType="Temporal">\n'
)
XDMF_TAIL = "    </Grid>\n  </Domain>\n</Xdmf>\n"
SNAPSHOT_LEVEL = 3  # Xdmf > Domain > Grid (temporal) > Grid (snapshot)


class XdmfIndex:
    """result.xdmf, grown in place on rank 0: the head, the snapshots, the closing tags.

    Every append is one ``pwrite`` of (new snapshot + closing tags) at the offset of the
    closing tags, so the file is a complete XDMF document before and after it.  A short
    write (disk full) puts the closing tags back and raises OSError.
    """

    def __init__(self, comm, descriptor: int | None, tail_offset: int):
        self.comm, self.descriptor, self.tail_offset = comm, descriptor, tail_offset

    @classmethod
    def create(cls, comm, path: pathlib.Path) -> XdmfIndex:
        """Write an XDMF document with no snapshot; collective (rank 0 writes)."""
        descriptor, error = None, None
        if comm.rank == 0:
            try:
                descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
                os.write(descriptor, (XDMF_HEAD + XDMF_TAIL).encode())
            except OSError as failure:
                error = f"cannot write {path}: {failure.strerror}"
        raise_everywhere(comm, None if error is None else OSError(error), root=0)
        return cls(comm, descriptor, len(XDMF_HEAD))

    def append(self, snapshot: str) -> int:
        """Add one snapshot; collective (rank 0 writes).  Returns the bytes written."""
        written, error = 0, None
        if self.comm.rank == 0:
            data = (snapshot + XDMF_TAIL).encode()
            try:
                written = os.pwrite(self._open_descriptor(), data, self.tail_offset)
                if written != len(data):
                    raise OSError(f"short write ({written} of {len(data)} bytes)")
                self.tail_offset += len(data) - len(XDMF_TAIL)
            except OSError as failure:
                self._restore_tail()
                error = f"cannot append to {XDMF_NAME}: {failure}"
        raise_everywhere(self.comm, None if error is None else OSError(error), root=0)
        return written

    def _restore_tail(self) -> None:
        """Cut the file back to the last complete snapshot and close it again (rank 0)."""
        descriptor = self._open_descriptor()
        os.pwrite(descriptor, XDMF_TAIL.encode(), self.tail_offset)
        os.ftruncate(descriptor, self.tail_offset + len(XDMF_TAIL))

    def _open_descriptor(self) -> int:
        """The open file (rank 0 only: the other ranks never write)."""
        if self.descriptor is None:
            raise OSError(f"{XDMF_NAME} is not open on this rank")
        return self.descriptor

    def close(self) -> None:
        if self.descriptor is not None:
            os.close(self.descriptor)
            self.descriptor = None


def snapshot_text(
    k: int, step: int, time: float, node_specs, contact_specs, n_nodes: int, n_contact: int
) -> str:
    """The indented ``<Grid>`` of output ``k`` (one line per element, newline-terminated)."""
    snapshot = ET.Element(
        "Grid", Name=f"output_{k:04d}", GridType="Collection", CollectionType="Spatial"
    )
    ET.SubElement(snapshot, "Time", Value=repr(time))
    ET.SubElement(snapshot, "Information", Name="step", Value=str(step))
    _point_grid(snapshot, "nodes", "mesh/coordinates", n_nodes, node_specs)
    if n_contact > 0:
        _point_grid(snapshot, "contact", "contact/coordinates", n_contact, contact_specs)
    ET.indent(snapshot, level=SNAPSHOT_LEVEL)
    indent = "  " * SNAPSHOT_LEVEL
    return indent + ET.tostring(snapshot, encoding="unicode") + "\n"


def _point_grid(parent, name: str, coordinates: str, n_points: int, specs: list) -> None:
    """A Uniform Polyvertex grid of ``n_points`` points with one attribute per field spec."""
    grid = ET.SubElement(parent, "Grid", Name=name, GridType="Uniform")
    topology = {"TopologyType": "Polyvertex", "NodesPerElement": "1"}
    ET.SubElement(grid, "Topology", topology, NumberOfElements=str(n_points))
    geometry = ET.SubElement(grid, "Geometry", GeometryType="XY")
    _data_item(geometry, coordinates, (n_points, 2), np.dtype(np.float64))
    for field_name, path, trailing, dtype in specs:
        kind = "Scalar" if not trailing else ("Vector" if trailing[0] in (2, 3) else "Matrix")
        attribute = ET.SubElement(
            grid, "Attribute", Name=field_name, AttributeType=kind, Center="Node"
        )
        _data_item(attribute, path, (n_points, *trailing), dtype)


def _data_item(parent, path: str, shape: tuple, dtype: np.dtype) -> None:
    """An HDF DataItem pointing at ``result.h5:/path``."""
    dtype = np.dtype(dtype)
    types = XDMF_BYTE_TYPES if dtype.itemsize == 1 else XDMF_NUMBER_TYPES
    number_type = types[dtype.kind]
    dimensions = " ".join(str(n) for n in shape)
    item = ET.SubElement(parent, "DataItem", Dimensions=dimensions, NumberType=number_type)
    item.attrib.update(Precision=str(dtype.itemsize), Format="HDF")
    item.text = f"{H5_NAME}:/{path}"
