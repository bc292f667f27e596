"""Applies the test suite's seed offset in the processes the suite starts (see ``seed_offset.py``)."""

import seed_offset

seed_offset.apply_on_import(seed_offset.offset_from_env())
