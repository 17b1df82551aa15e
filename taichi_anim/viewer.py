"""Live 3D viewer on Taichi's GGUI (Vulkan): particles, line segments and a triangle mesh per frame."""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import glob
import os
import sys
from pathlib import Path

import numpy as np
import taichi as ti

from . import runtime, validate
from .errors import ParameterError
from .io.export import area_weighted_normals, atomic_path
from .render import fit_camera
from .render.image import _segments

INSTALL_HINT = (
    "on Debian/Ubuntu: apt-get install libvulkan1 mesa-vulkan-drivers (lavapipe, a software Vulkan driver; "
    "or your GPU's Vulkan driver)"
)
DISPLAY_HINT = (
    "run under a virtual display: apt-get install xvfb, then xvfb-run -a python your_script.py; "
    "or pass show_window=False to render offscreen"
)


class ViewerUnavailable(RuntimeError):
    """GGUI cannot open a window here; the message says what is missing and how to install it."""


# ----------------------------------------------------------------------------------------- diagnosis


def _loader_names() -> tuple[str, ...]:
    if sys.platform.startswith("win"):
        return ("vulkan-1.dll",)
    if sys.platform == "darwin":
        return ("libvulkan.1.dylib", "libMoltenVK.dylib")
    return ("libvulkan.so.1",)


def _icd_manifests() -> tuple[list[str], list[str]]:
    """(directories searched, ICD manifest files found), following the Linux loader's search order."""
    explicit = os.environ.get("VK_DRIVER_FILES") or os.environ.get("VK_ICD_FILENAMES")
    if explicit:
        files = [f for f in explicit.split(os.pathsep) if f]
        return files, [f for f in files if os.path.exists(f)]
    config = os.environ.get("XDG_CONFIG_DIRS", "/etc/xdg").split(os.pathsep)
    data = os.environ.get("XDG_DATA_DIRS", "/usr/local/share:/usr/share").split(os.pathsep)
    home = os.environ.get("XDG_DATA_HOME", os.path.expanduser("~/.local/share"))
    dirs = [os.path.join(d, "vulkan", "icd.d") for d in [*config, "/etc", home, *data] if d]
    return dirs, sorted(f for d in dirs for f in glob.glob(os.path.join(d, "*.json")))


class _VkInstanceCreateInfo(ctypes.Structure):
    _fields_ = [
        ("sType", ctypes.c_int),
        ("pNext", ctypes.c_void_p),
        ("flags", ctypes.c_uint32),
        ("pApplicationInfo", ctypes.c_void_p),
        ("enabledLayerCount", ctypes.c_uint32),
        ("ppEnabledLayerNames", ctypes.c_void_p),
        ("enabledExtensionCount", ctypes.c_uint32),
        ("ppEnabledExtensionNames", ctypes.c_void_p),
    ]


@functools.lru_cache(maxsize=1)
def _vulkan_device_problem() -> str | None:
    """Load the Vulkan loader and count physical devices, as GGUI will (cached: it loads drivers)."""
    lib, tried = None, []
    for name in _loader_names():
        try:
            lib = ctypes.CDLL(name)
            break
        except OSError as e:
            tried.append(f"{name} ({e})")
    if lib is None:
        return f"the Vulkan loader is not installed (could not load {'; '.join(tried)}); {INSTALL_HINT}"
    info = _VkInstanceCreateInfo(sType=1)  # VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO, everything else empty
    instance = ctypes.c_void_p()
    lib.vkCreateInstance.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.POINTER(ctypes.c_void_p)]
    lib.vkCreateInstance.restype = ctypes.c_int
    result = lib.vkCreateInstance(ctypes.byref(info), None, ctypes.byref(instance))
    if result != 0:
        dirs, found = _icd_manifests()
        # -9 is VK_ERROR_INCOMPATIBLE_DRIVER: the loader found no usable driver (ICD).
        return (
            f"the Vulkan loader is installed but could not create an instance (VkResult {result}); "
            f"no usable Vulkan driver (ICD): manifests found: {found or 'none'} "
            f"(searched {', '.join(dirs)}); {INSTALL_HINT}"
        )
    try:
        count = ctypes.c_uint32(0)
        lib.vkEnumeratePhysicalDevices.argtypes = [
            ctypes.c_void_p,
            ctypes.POINTER(ctypes.c_uint32),
            ctypes.c_void_p,
        ]
        lib.vkEnumeratePhysicalDevices.restype = ctypes.c_int
        lib.vkEnumeratePhysicalDevices(instance, ctypes.byref(count), None)
    finally:
        lib.vkDestroyInstance.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
        lib.vkDestroyInstance(instance, None)
    if count.value == 0:
        dirs, found = _icd_manifests()
        return (
            f"Vulkan has no device: ICD manifests found: {found or 'none'} "
            f"(searched {', '.join(dirs)}); {INSTALL_HINT}"
        )
    return None


def _display_problem() -> str | None:
    if not sys.platform.startswith("linux"):
        return None  # Windows and macOS always have a window system
    if os.environ.get("WAYLAND_DISPLAY"):
        return None
    display = os.environ.get("DISPLAY")
    if not display:
        return f"no display: neither DISPLAY nor WAYLAND_DISPLAY is set; {DISPLAY_HINT}"
    # GLFW cannot be asked safely: when it fails to connect, Taichi prints "cannot initialize GLFW" and
    # ends the whole process. Try the X connection ourselves first.
    name = ctypes.util.find_library("X11") or "libX11.so.6"
    try:
        x11 = ctypes.CDLL(name)
    except OSError:
        return f"DISPLAY={display} is set but libX11 is missing (apt-get install libx11-6); {DISPLAY_HINT}"
    x11.XOpenDisplay.restype = ctypes.c_void_p
    x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
    handle = x11.XOpenDisplay(None)
    if not handle:
        return f"cannot connect to the X display DISPLAY={display}; {DISPLAY_HINT}"
    x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
    x11.XCloseDisplay(handle)
    return None


def vulkan_problem(*, show_window: bool = True) -> str | None:
    """Why GGUI cannot run here, as one actionable sentence, or None if it should work.

    Checks, without opening a window: Taichi built with GGUI; a display when show_window (Linux:
    DISPLAY or WAYLAND_DISPLAY, and the X server reachable); the Vulkan loader (libvulkan.so.1); and a
    Vulkan driver (ICD) that exposes at least one device.
    """
    from taichi._lib import core as _ti_core

    if not getattr(_ti_core, "GGUI_AVAILABLE", False):
        return "this Taichi build has no GGUI (a restricted wheel); install the full taichi wheel from PyPI"
    if show_window:
        problem = _display_problem()
        if problem:
            return problem
    return _vulkan_device_problem()


# -------------------------------------------------------------------------------------------- viewer


class _Buffer:
    """A Taichi field of `width`-vectors (or scalars) that grows to fit, filled from NumPy each frame."""

    def __init__(self, width: int, dtype):
        self.width, self.dtype, self.field, self.capacity = width, dtype, None, 0

    def upload(self, data: np.ndarray, *, minimum: int = 0, exact: int | None = None):
        """Copy `data` into the field, reallocating when it does not fit (or to `exact` elements).

        GGUI copies companion fields (colours, normals) over the range of the positions field, so those
        are allocated with exactly the positions' capacity.
        """
        n = len(data)
        want = (
            exact
            if exact is not None
            else (self.capacity if n <= self.capacity else max(n, 2 * self.capacity, minimum, 1))
        )
        if want != self.capacity or self.field is None:
            # Doubling keeps reallocations (each a new Taichi SNode tree) rare while a scene grows.
            self.capacity = want
            shape = (want, self.width) if self.width > 1 else (want,)
            self.field = (
                ti.Vector.field(self.width, self.dtype, want)
                if self.width > 1
                else ti.field(self.dtype, want)
            )
            self._host = np.zeros(shape, np.int32 if self.dtype == ti.i32 else np.float32)
        self._host[:n] = data
        self._host[n:] = 0
        self.field.from_numpy(self._host)
        return self.field


class Viewer:
    """A GGUI window showing particles, line segments and a triangle mesh, one `draw` call per frame.

    title: window title; res: (width, height) pixels; capacity: particles to allocate for up front (the
    buffers grow when more are drawn). show_window=False renders offscreen (no display needed, Vulkan
    still is); camera: a taichi_anim.render.Camera, or None to fit the first frame's bounds. In a window,
    hold the right mouse button to turn, W/A/S/D/Q/E to move, Esc to close.
    Raises ViewerUnavailable (with what to install) when GGUI cannot run here.
    """

    def __init__(
        self,
        title: str = "taichi_anim",
        res: tuple[int, int] = (1280, 720),
        capacity: int = 1 << 16,
        *,
        show_window: bool = True,
        camera=None,
        background=(0.063, 0.078, 0.094),
        vsync: bool = True,
    ):
        capacity = validate.count("capacity", capacity, 1)
        res = (validate.count("res[0]", res[0], 1), validate.count("res[1]", res[1], 1))
        problem = vulkan_problem(show_window=show_window)
        if problem:
            raise ViewerUnavailable(f"cannot open a GGUI window: {problem}")
        runtime.ensure_initialized()  # GGUI works with arch=cpu as well as vulkan/cuda
        try:
            self._window = ti.ui.Window(title, res, vsync=vsync, show_window=show_window)
        except RuntimeError as e:
            if "Vulkan" in str(e) or "GGUI" in str(e):
                raise ViewerUnavailable(
                    f"{e}: {INSTALL_HINT}; for a window without a display: {DISPLAY_HINT}"
                ) from e
            raise
        self.show_window = show_window
        self.res = res
        self._canvas = self._window.get_canvas()
        self._scene = self._window.get_scene()
        self._camera = ti.ui.Camera()
        self._camera_set = False
        self._speed = 0.03
        if camera is not None:
            self._set_camera(camera)
        self._background = tuple(float(c) for c in background)
        self._capacity = capacity
        self._buf = {
            name: _Buffer(3, ti.f32)
            for name in (
                "points",
                "colors",
                "line_points",
                "line_colors",
                "mesh_vertices",
                "mesh_normals",
                "mesh_colors",
            )
        }
        self._buf["mesh_indices"] = _Buffer(1, ti.i32)
        self.last_image: np.ndarray | None = None
        self._closed = False

    # ----------------------------------------------------------------------------------------- camera
    def _set_camera(self, cam) -> None:
        self._camera.position(*cam.eye)
        self._camera.lookat(*cam.target)
        self._camera.up(*cam.up)
        self._camera.fov(cam.fov_deg)
        self._camera.z_near(max(cam.near, 1e-4))
        # Move about 1 % of the viewing distance per frame at 60 fps.
        self._speed = 0.01 * float(np.linalg.norm(np.subtract(cam.target, cam.eye)))
        self._camera_set = True

    @property
    def running(self) -> bool:
        """False once the window was closed (by the user, Esc, or close())."""
        return not self._closed and self._window.running

    # ------------------------------------------------------------------------------------------- draw
    def draw(
        self,
        points=None,
        colors=None,
        radius: float = 0.01,
        *,
        lines=None,
        line_colors=None,
        line_width: float = 1.0,
        triangles=None,
        mesh_color=(0.72, 0.75, 0.8),
        mesh_colors=None,
        screenshot: str | os.PathLike | None = None,
    ) -> bool:
        """Show one frame and return whether the window is still open.

        points: (N,3) [m]; colors: (N,3) RGB in [0,1] or one RGB triple; radius: particle radius [m].
        lines: (begin (M,3), end (M,3)) or (points (P,3), indices (L,2) int); line_colors: (M,3) or one
        RGB; line_width: pixels. triangles: (vertices (V,3), faces (F,3) int), shaded two-sided with
        area-weighted normals; mesh_color: one RGB, or mesh_colors: (V,3) per vertex.
        screenshot: also save this frame as an image (atomic write). Offscreen, a frame without a
        screenshot is kept in `last_image` ((H,W,3) uint8, top row first).
        """
        if not self.running:
            return False
        if self.show_window:
            for e in self._window.get_events(ti.ui.PRESS):
                if e.key == ti.ui.ESCAPE:
                    self.close()
                    return False
        frame = self._prepare(
            points, colors, radius, lines, line_colors, line_width, triangles, mesh_color, mesh_colors
        )
        if self.show_window:
            self._camera.track_user_inputs(self._window, movement_speed=self._speed, hold_key=ti.ui.RMB)
        self._submit(frame)
        if screenshot is not None:
            with atomic_path(screenshot) as tmp:
                self._window.save_image(str(tmp))  # consumes this frame's draw list
                if not Path(tmp).exists():
                    raise OSError(f"GGUI wrote no image to {screenshot}")
            if self.show_window:
                self._submit(frame)
                self._window.show()
        elif self.show_window:
            self._window.show()
        else:
            img = self._window.get_image_buffer_as_numpy()  # (W,H,4) float, row 0 at the bottom
            self.last_image = np.ascontiguousarray(
                np.clip(np.round(img[:, ::-1, :3].transpose(1, 0, 2) * 255.0), 0, 255).astype(np.uint8)
            )
        return self.running

    def _prepare(
        self, points, colors, radius, lines, line_colors, line_width, triangles, mesh_color, mesh_colors
    ):
        """Validate and upload this frame's data; returns the scene calls to replay."""
        calls = []
        bounds = []
        if points is not None:
            p = validate.finite_array("points", points, (3,))
            if len(p):
                radius = validate.positive("radius", radius)
                field = self._buf["points"].upload(p, minimum=self._capacity)
                cap = self._buf["points"].capacity
                kw = dict(radius=radius, index_count=len(p))
                if colors is not None and np.shape(colors) != (3,):
                    kw["per_vertex_color"] = self._buf["colors"].upload(
                        validate.colors("colors", colors, len(p)), exact=cap
                    )
                else:
                    kw["color"] = self._rgb("colors", colors, (0.95, 0.78, 0.43))
                calls.append(("particles", field, kw))
                bounds.append(p)
        if lines is not None:
            begin, end = _segments(lines)
            if len(begin):
                seg = np.stack([begin, end], axis=1).reshape(-1, 3)
                field = self._buf["line_points"].upload(seg)
                cap = self._buf["line_points"].capacity
                kw = dict(width=validate.positive("line_width", line_width), vertex_count=len(seg))
                if line_colors is not None and np.shape(line_colors) != (3,):
                    c = validate.colors("line_colors", line_colors, len(begin))
                    kw["per_vertex_color"] = self._buf["line_colors"].upload(
                        np.repeat(c, 2, axis=0), exact=cap
                    )
                else:
                    kw["color"] = self._rgb("line_colors", line_colors, (0.5, 0.7, 1.0))
                calls.append(("lines", field, kw))
                bounds.append(seg)
        if triangles is not None:
            if not isinstance(triangles, (tuple, list)) or len(triangles) != 2:
                raise ParameterError("triangles must be (vertices (V,3), faces (F,3) int)")
            v = validate.finite_array("triangles[0] (vertices)", triangles[0], (3,))
            f = validate.indices("triangles[1] (faces)", triangles[1], 3, len(v), "vertices")
            if len(f):
                vertices = self._buf["mesh_vertices"].upload(v)
                cap = self._buf["mesh_vertices"].capacity
                kw = dict(
                    indices=self._buf["mesh_indices"].upload(f.reshape(-1)),
                    normals=self._buf["mesh_normals"].upload(area_weighted_normals(v, f), exact=cap),
                    two_sided=True,
                    vertex_count=len(v),
                    index_count=3 * len(f),
                )
                if mesh_colors is not None:
                    c = validate.colors("mesh_colors", mesh_colors, len(v))
                    kw["per_vertex_color"] = self._buf["mesh_colors"].upload(c, exact=cap)
                else:
                    kw["color"] = self._rgb("mesh_color", mesh_color, (0.72, 0.75, 0.8))
                calls.append(("mesh", vertices, kw))
                bounds.append(v[np.unique(f)])
        if not self._camera_set:
            cloud = np.concatenate(bounds) if bounds else np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
            w, h = self.res
            self._set_camera(fit_camera(cloud.min(0), cloud.max(0), resolution=(w + w % 2, h + h % 2)))
        return calls

    @staticmethod
    def _rgb(name: str, value, default) -> tuple[float, float, float]:
        if value is None:
            return default
        return tuple(float(c) for c in validate.colors(name, np.asarray(value).reshape(1, 3), 1)[0])

    def _submit(self, calls) -> None:
        scene = self._scene
        scene.set_camera(self._camera)
        scene.ambient_light((0.35, 0.35, 0.35))
        scene.point_light(pos=tuple(self._camera.curr_position), color=(0.8, 0.8, 0.8))
        for kind, field, kw in calls:
            getattr(scene, kind)(field, **kw)
        self._canvas.set_background_color(self._background)
        self._canvas.scene(scene)

    def close(self) -> None:
        """Close the window; later draw() calls return False."""
        if not self._closed:
            self._closed = True
            self._window.running = False
            self._window.destroy()

    def __enter__(self) -> Viewer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
