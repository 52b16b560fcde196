"""Analysis: measurement records, fitting, calibration, the discrepancy workflow, the paper.

* ``records``: the record format (``docs/record-format.md``): the strict reader and the writer;
* ``recorder``: live records from polls (``tactile-gateway record``);
* ``fitting``: least-squares fits of the model to a record, with intervals and quality;
* ``calibration``: per-channel calibration files;
* ``discrepancy`` / ``discrepancy_report``: find, name and add the missing effect;
* ``paper``: the paper's experiments replayed; ``plots``: figures.
"""
