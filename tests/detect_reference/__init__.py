"""The numpy detection path as it was before the core did it (``isa.detection`` planes, verify,
refine and multi at merge-api 954ca54: their algorithms, unchanged, sharing the parameter and
result types that stayed in ``isa.detection``): the reference the core's ``detect`` is compared
with in tests/test_detection_core.py and timed against in benches/bench_detect.py."""
