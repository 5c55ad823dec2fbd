"""Test fakes (``from fakes.hardware import ...``; ``tests/`` is on the path
through ``tests/conftest.py``): stand-ins that say they are fakes and are no
part of the ``lmap_drake`` product."""
