"""The pinch kernel file is read without importing pandas (pq.read_table's dataset layer and pyarrow's to_numpy
both pull it in: 0.3 s of a dry run's start, in the main process and in the skin worker), and what is read is
the file's columns exactly."""

import os
import subprocess
import sys

import numpy as np
import pyarrow.parquet as pq

from neatskin.skin.kernel import packaged_kernel_path, read_kernel


def test_the_pinch_kernel_is_read_without_pandas():
    code = (
        "import sys; from neatskin.skin.kernel import read_kernel, packaged_kernel_path; "
        "read_kernel(packaged_kernel_path()); print('pandas' in sys.modules)"
    )
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert out.stdout.strip() == "False"


def test_the_kernel_read_is_the_files_columns_exactly():
    kernel, table = read_kernel(packaged_kernel_path()), pq.read_table(packaged_kernel_path())
    shape = kernel.area_ratio.shape
    assert kernel.extra  # the quasi-3D kernel's extra columns are compared too
    for name, got in (("area_ratio", kernel.area_ratio), ("force_n", kernel.force_n), *kernel.extra.items()):
        want = table.column(name).to_numpy().reshape(shape)
        assert got.dtype == want.dtype and np.array_equal(got, want, equal_nan=True), name
        assert got.flags.writeable  # a copy of its own, not a read-only view of pyarrow's buffer
    assert np.array_equal(kernel.offsets_mm, np.unique(table.column("offset_mm").to_numpy()))
    assert np.array_equal(kernel.depths_mm, np.unique(table.column("depth_mm").to_numpy()))
