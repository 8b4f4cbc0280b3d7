"""Writes the golden GCSArray files with PIPython's own writer (`pitools.savegcsarray`).

PIPython 2.11.0.6 (`pip download pipython`), PI's proprietary-licensed Python package; only its
output (numbers we chose) is committed. Its package imports pyusb at import time: install
`pyusb`, or put empty `usb`, `usb.core`, `usb.util`, `usb.backend.libusb0/1` modules on
PYTHONPATH — the writer does not use them.

Run: python3 make.py   (from this directory)
Values: row i (0-based) — table 1 commanded position 10·i µm, table 2 the reference 10·i +
0.001·i µm, table 3 a temperature 22 + 0.01·i °C, table 4 a sensor voltage 1 + 0.5·i.
"""
from collections import OrderedDict

from pipython import pitools

N = 12
cmd = [10.0 * i for i in range(N)]
meas = [10.0 * i + 0.001 * i for i in range(N)]
temp = [22.0 + 0.01 * i for i in range(N)]
volt = [1.0 + 0.5 * i for i in range(N)]

# a header as qDRR() returns it from a controller: sample time and one NAME per table
header = OrderedDict([('VERSION', 1), ('TYPE', 1), ('SEPARATOR', 32), ('DIM', 4),
                      ('SAMPLE_TIME', 0.5), ('NDATA', N),
                      ('NAME0', 'Commanded Position of axis 1'),
                      ('NAME1', 'Position of axis 1'),
                      ('NAME2', 'Temperature base'),
                      ('NAME3', 'Input Signal Value of channel 5')])
pitools.savegcsarray('pipython_qdrr_space.gcs', header, [cmd, meas, temp, volt])

# PIPython's default header (no sample time, no names), tab-separated
header = OrderedDict([('VERSION', 1), ('TYPE', 1), ('SEPARATOR', 9), ('DIM', 3), ('NDATA', N)])
pitools.savegcsarray('pipython_tab.gcs', header, [cmd, meas, temp])
