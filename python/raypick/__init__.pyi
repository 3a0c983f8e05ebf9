# Type stubs for raypick (the compiled half is raypick._raypick). Checked against the module
# by python/tests/test_stubs.py: the same names, parameters and defaults.

from os import PathLike
from typing import Any, Literal, Optional, Sequence, Tuple, Union, final

import numpy as np
import numpy.typing as npt

from . import dask as dask

_Path = Union[str, PathLike[str]]
_Rays = Union[npt.ArrayLike, Tuple[npt.ArrayLike, npt.ArrayLike]]
_Builder = Literal["auto", "median-cut", "sah", "grid"]
_Backend = Literal["auto", "gpu", "cpu", "reference"]

__all__ = ["Scene", "camera_rays", "dask", "max_memory", "set_max_memory"]

@final
class Scene:
    """A built scene: its triangles and the tree over them, ready to pick."""

    @staticmethod
    def load(
        paths: Union[_Path, Sequence[_Path]],
        masks: Optional[Union[int, Sequence[Optional[int]]]] = None,
        builder: Optional[_Builder] = None,
        leaf_size: Optional[int] = None,
    ) -> Scene: ...
    @staticmethod
    def from_arrays(
        vertices: npt.ArrayLike,
        triangles: npt.ArrayLike,
        builder: _Builder = "auto",
        leaf_size: int = 8,
    ) -> Scene: ...
    def save(self, path: _Path) -> None: ...
    def pick(
        self,
        rays: _Rays,
        mode: Literal["closest", "any", "all"] = "closest",
        max_hits: int = 16,
        cull: Literal["none", "back", "front"] = "none",
        tmin: float = 0.0,
        tmax: float = ...,
        ray_mask: int = 0xFFFFFFFF,
        intersector: Literal["watertight", "moller-trumbore"] = "watertight",
        backend: _Backend = "auto",
    ) -> dict[str, np.ndarray]: ...
    def los(
        self,
        a: npt.ArrayLike,
        b: npt.ArrayLike,
        epsilon: float = 1e-06,
        ray_mask: int = 0xFFFFFFFF,
        backend: _Backend = "auto",
    ) -> np.ndarray: ...
    def viewshed(
        self,
        observer: npt.ArrayLike,
        targets: Optional[npt.ArrayLike] = None,
        target_height: float = 0.0,
        epsilon: float = 1e-06,
        ray_mask: int = 0xFFFFFFFF,
        backend: _Backend = "auto",
    ) -> dict[str, np.ndarray]: ...
    @property
    def triangle_count(self) -> int: ...
    @property
    def objects(self) -> list[dict[str, Any]]: ...
    @property
    def bounds(self) -> Optional[Tuple[np.ndarray, np.ndarray]]: ...

def camera_rays(
    camera: Union[dict[str, Any], str], pixels: Optional[npt.ArrayLike] = None
) -> np.ndarray: ...
def max_memory() -> int: ...
def set_max_memory(size: Union[int, str]) -> int: ...

# For raypick.dask's worker processes: the threads a pick runs on in this process.
def _set_threads(threads: int) -> None: ...
def _threads() -> int: ...
