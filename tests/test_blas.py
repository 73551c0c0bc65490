"""stillcap._blas: the BLAS thread limit's controller finds the libraries threadpoolctl's own
search finds."""
import sys


def test_the_name_filtered_controller_finds_what_threadpoolctl_finds():
    import cv2  # noqa: F401  (OpenCV's own OpenBLAS, among ~140 loaded libraries)
    import scipy.linalg  # noqa: F401
    from threadpoolctl import ThreadpoolController

    from stillcap._blas import _blas_controller, _NamedLibrariesController

    full = ThreadpoolController().info()
    fast = _NamedLibrariesController().info()

    def by_path(infos):
        return sorted(infos, key=lambda d: d["filepath"])

    assert by_path(fast) == by_path(full)
    assert any(d["user_api"] == "blas" for d in fast)
    if sys.platform.startswith("linux"):
        assert isinstance(_blas_controller(), _NamedLibrariesController)


def test_the_limit_holds_inside_and_the_setting_comes_back():
    from threadpoolctl import threadpool_info, threadpool_limits

    from stillcap._blas import single_blas_thread

    def blas_threads():
        return sorted({d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"})

    with threadpool_limits(2, user_api="blas"):
        with single_blas_thread():
            assert blas_threads() == [1]
        assert blas_threads() == [2]


def test_a_changed_threadpoolctl_falls_back_to_its_own_search(monkeypatch):
    import threadpoolctl

    import stillcap._blas as blas

    monkeypatch.delattr(threadpoolctl, "_ALL_PREFIXES")
    blas._blas_controller.cache_clear()
    try:
        ctl = blas._blas_controller()
        assert type(ctl) is threadpoolctl.ThreadpoolController
        assert any(d["user_api"] == "blas" for d in ctl.info())
    finally:
        blas._blas_controller.cache_clear()
