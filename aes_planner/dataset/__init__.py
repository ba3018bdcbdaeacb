"""Posed-frame datasets: the package's own folder format and importers for common formats.

See :mod:`aes_planner.dataset.folder` for the folder layout and ``cameras.json`` schema, and
:mod:`aes_planner.dataset.importers` for nerfstudio and RealEstate10K.
"""

from aes_planner.dataset.folder import DatasetError, PosedDataset, load_dataset, save_dataset
from aes_planner.dataset.importers import align_up_to_cameras, import_nerfstudio, import_re10k

__all__ = [
    "DatasetError",
    "PosedDataset",
    "align_up_to_cameras",
    "import_nerfstudio",
    "import_re10k",
    "load_dataset",
    "save_dataset",
]
