"""Analysis: measurement records, fitting, calibration, the discrepancy workflow, the paper.

* ``records``: the record format (``docs/record-format.md``): the strict reader and the writer;
* ``recorder``: live records from polls (``tactile-gateway record``);
* ``fitting`` / ``objectives``: least-squares fits of the model to a record (log-R or force
  residuals, an optional reference zero offset), with intervals and quality;
* ``measurement``: the noise model of a record's read-out; ``rivals``: the line and the lookup;
* ``calibration``: per-channel calibration files;
* ``discrepancy`` / ``discrepancy_report``: find, name and add the missing effect;
* ``paper``: the paper's experiments replayed; ``plots``: figures.
"""
