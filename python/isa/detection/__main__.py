"""``python -m isa.detection``, the command's name before ``python -m isa detect-real`` (kept for
one release, like the old module paths of :mod:`isa._compat`)."""

import warnings

from isa.detection.cli import main

if __name__ == "__main__":
    warnings.warn("python -m isa.detection is now python -m isa detect-real; the old name will be removed in the next "
                  "release", DeprecationWarning, stacklevel=1)
    main()
