"""Reports: the Markdown + PNG report (``report``) and its figures (``figures``).

Public names are re-exported lazily (``lazy_loader``): importing the package loads none of its
modules, so ``import isa.report`` pulls in no OpenGL or OpenCV until a name that needs them is used.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach(
    __name__,
    submodules=["report", "figures"],
    submod_attrs={
        "report": [
            "Report",
        ],
    },
)
