"""Stereo calibration readers: KITTI, Middlebury, OpenCV YAML/XML, plain YAML."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from o3d_terrain.errors import InputError
from o3d_terrain.stereo import StereoCalibration, load_calibration

F, CX, CY, BASELINE = 700.0, 320.5, 240.25, 0.12


def kitti_text(f=F, cx=CY * 0 + CX, cy=CY, baseline=BASELINE, offset=0.06, extra=True):
    """A KITTI object calib.txt: P0/P1 grey pair, P2/P3 colour pair shifted by ``offset`` m."""
    def p(tx):
        return np.array([[f, 0, cx, tx * f], [0, f, cy, 0], [0, 0, 1, 0]])

    rows = {"P0": p(0.0), "P1": p(-baseline * 1.1), "P2": p(offset), "P3": p(offset - baseline)}
    lines = [f"{k}: " + " ".join(f"{v:.12e}" for v in m.ravel()) for k, m in rows.items()]
    if extra:
        r0 = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))[0]
        tr = np.hstack([np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]], float), [[0.1], [-0.05], [-0.3]]])
        lines.append("R0_rect: " + " ".join(f"{v:.12e}" for v in r0.ravel()))
        lines.append("Tr_velo_to_cam: " + " ".join(f"{v:.12e}" for v in tr.ravel()))
    return "\n".join(lines) + "\n", rows


def write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_kitti_colour_pair_is_the_default(tmp_path):
    text, _ = kitti_text()
    calib = load_calibration(write(tmp_path, "calib.txt", text))
    assert calib.fx == pytest.approx(F) and calib.cx == pytest.approx(CX) and calib.cy == pytest.approx(CY)
    assert calib.baseline == pytest.approx(BASELINE)
    assert calib.doffs == 0.0


def test_kitti_grey_pair_on_request(tmp_path):
    text, _ = kitti_text()
    calib = load_calibration(write(tmp_path, "calib.txt", text), cameras=("P0", "P1"))
    assert calib.baseline == pytest.approx(BASELINE * 1.1)


def test_kitti_lidar_to_camera_projects_like_the_kitti_devkit(tmp_path):
    # devkit: pixel = P2 · R0_rect · Tr_velo_to_cam · X; ours: pixel = K · lidar_to_camera · X
    text, rows = kitti_text()
    calib = load_calibration(write(tmp_path, "calib.txt", text))
    lines = dict(line.split(":", 1) for line in text.splitlines())
    r0 = np.eye(4)
    r0[:3, :3] = np.array(lines["R0_rect"].split(), float).reshape(3, 3)
    tr = np.eye(4)
    tr[:3, :] = np.array(lines["Tr_velo_to_cam"].split(), float).reshape(3, 4)
    rng = np.random.default_rng(0)
    points = np.c_[rng.uniform(5, 40, 50), rng.uniform(-10, 10, 50), rng.uniform(-2, 1, 50), np.ones(50)]
    devkit = (rows["P2"] @ r0 @ tr @ points.T).T
    ours = (calib.camera_matrix @ (calib.lidar_to_camera @ points.T)[:3]).T
    np.testing.assert_allclose(devkit[:, :2] / devkit[:, 2:], ours[:, :2] / ours[:, 2:], atol=1e-6)


def test_kitti_missing_key_is_named(tmp_path):
    text, _ = kitti_text(extra=False)
    text = "\n".join(line for line in text.splitlines() if not line.startswith("P3"))
    with pytest.raises(InputError, match="P3"):
        load_calibration(write(tmp_path, "calib.txt", text), cameras=("P2", "P3"))


def test_kitti_swapped_cameras_are_reported(tmp_path):
    text, _ = kitti_text()
    with pytest.raises(InputError, match="swapped"):
        load_calibration(write(tmp_path, "calib.txt", text), cameras=("P3", "P2"))


def test_projections_of_an_unrectified_pair_are_rejected(tmp_path):
    text, rows = kitti_text(extra=False)
    p3 = rows["P3"].copy()
    p3[1, 2] += 5.0
    text = text.replace("P3: " + " ".join(f"{v:.12e}" for v in rows["P3"].ravel()),
                        "P3: " + " ".join(f"{v:.12e}" for v in p3.ravel()))
    with pytest.raises(InputError, match="rectif"):
        load_calibration(write(tmp_path, "calib.txt", text))


MIDDLEBURY = """cam0=[999.421 0 294.182; 0 999.421 252.932; 0 0 1]
cam1=[999.421 0 326.96; 0 999.421 252.932; 0 0 1]
doffs=32.778
baseline=193.001
width=741
height=497
ndisp=70
"""


def test_middlebury(tmp_path):
    calib = load_calibration(write(tmp_path, "calib.txt", MIDDLEBURY))
    assert calib.baseline == pytest.approx(0.193001)  # millimetres -> metres
    assert calib.doffs == pytest.approx(326.96 - 294.182, abs=1e-3)
    assert (calib.width, calib.height) == (741, 497)
    assert calib.disparity_hint == (0.0, 70.0)
    # depth = baseline · f / (d + doffs), the Middlebury formula
    assert calib.depth_from_disparity(40.0) == pytest.approx(0.193001 * 999.421 / (40 + 32.778))
    assert calib.disparity_from_depth(calib.depth_from_disparity(40.0)) == pytest.approx(40.0)


def test_middlebury_missing_key(tmp_path):
    text = "\n".join(line for line in MIDDLEBURY.splitlines() if not line.startswith("baseline"))
    with pytest.raises(InputError, match="baseline"):
        load_calibration(write(tmp_path, "calib.txt", text))


def _opencv_raw():
    m1 = np.array([[F, 0, 318.0], [0, F + 2, 241.0], [0, 0, 1]])
    m2 = np.array([[F + 3, 0, 322.0], [0, F + 1, 238.0], [0, 0, 1]])
    d1 = np.array([-0.05, 0.01, 0.0, 0.0, 0.0])
    d2 = np.array([-0.04, 0.012, 0.0, 0.0, 0.0])
    r = cv2.Rodrigues(np.array([0.002, 0.01, -0.003]))[0]
    t = np.array([[-BASELINE], [0.001], [0.0005]])
    return m1, d1, m2, d2, r, t


def _write_storage(path, **nodes):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in nodes.items():
        fs.write(key, value)
    fs.release()
    return path


def test_opencv_yaml_xml_forms_agree(tmp_path):
    m1, d1, m2, d2, r, t = _opencv_raw()
    size = (640, 480)
    r1, r2, p1, p2, q, _, _ = cv2.stereoRectify(m1, d1, m2, d2, size, r, t,
                                                flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    from_p = load_calibration(_write_storage(tmp_path / "p.yaml", P1=p1, P2=p2))
    from_q = load_calibration(_write_storage(tmp_path / "q.xml", Q=q))
    from_raw = load_calibration(_write_storage(tmp_path / "raw.yml", M1=m1, D1=d1, M2=m2, D2=d2,
                                               R=r, T=t, image_width=640, image_height=480))
    for calib in (from_q, from_raw):
        assert calib.fx == pytest.approx(from_p.fx)
        assert calib.cx == pytest.approx(from_p.cx)
        assert calib.cy == pytest.approx(from_p.cy)
        assert calib.baseline == pytest.approx(from_p.baseline)
        assert calib.doffs == pytest.approx(from_p.doffs, abs=1e-9)
    assert from_p.baseline == pytest.approx(np.linalg.norm(t))
    assert from_raw.unrectified is not None
    # our Q reproduces OpenCV's Q on the 3-D points it gives
    d = np.full((4, 4), 20.0, np.float32)
    np.testing.assert_allclose(cv2.reprojectImageTo3D(d, from_p.Q), cv2.reprojectImageTo3D(d, q), rtol=1e-6)


def test_opencv_raw_without_size_is_resolved_from_the_images(tmp_path):
    m1, d1, m2, d2, r, t = _opencv_raw()
    calib = load_calibration(_write_storage(tmp_path / "raw.yaml", M1=m1, D1=d1, M2=m2, D2=d2, R=r, T=t))
    resolved = calib.for_images(640, 480)
    assert (resolved.width, resolved.height) == (640, 480)
    assert resolved.baseline == pytest.approx(np.linalg.norm(t))


def test_opencv_missing_keys_are_listed(tmp_path):
    m1, d1, m2, d2, r, t = _opencv_raw()
    path = _write_storage(tmp_path / "raw.yaml", M1=m1, D1=d1, M2=m2, D2=d2)
    with pytest.raises(InputError, match="misses R, T"):
        load_calibration(path)


def test_plain_yaml(tmp_path):
    path = write(tmp_path, "cam.yaml", "fx: 500\ncx: 320\ncy: 240\nbaseline: 0.2\nwidth: 640\nheight: 480\n")
    calib = load_calibration(path)
    assert (calib.fx, calib.fy, calib.cx, calib.cy, calib.baseline) == (500, 500, 320, 240, 0.2)
    assert (calib.width, calib.height) == (640, 480)


def test_plain_yaml_reports_every_problem(tmp_path):
    path = write(tmp_path, "cam.yaml", "fx: 500\ncx: 320\nbasline: 0.2\n")
    with pytest.raises(InputError) as info:
        load_calibration(path)
    text = str(info.value)
    assert "did you mean 'baseline'" in text and "missing key 'cy'" in text


def test_plain_yaml_with_opencv_keys(tmp_path):
    path = write(tmp_path, "cam.yaml",
                 "P1: [[500, 0, 320, 0], [0, 500, 240, 0], [0, 0, 1, 0]]\n"
                 "P2: [[500, 0, 320, -100], [0, 500, 240, 0], [0, 0, 1, 0]]\n")
    assert load_calibration(path).baseline == pytest.approx(0.2)


@pytest.mark.parametrize("text", ["", "hello world\n"])
def test_unrecognised_files(tmp_path, text):
    with pytest.raises(InputError):
        load_calibration(write(tmp_path, "calib.txt", text))


def test_missing_file():
    with pytest.raises(InputError, match="no such calibration file"):
        load_calibration("/nonexistent/calib.txt")


def test_invalid_values_are_named():
    with pytest.raises(InputError, match="baseline"):
        StereoCalibration(fx=500, fy=500, cx=320, cy=240, baseline=-0.1)
    with pytest.raises(InputError, match="fx"):
        StereoCalibration(fx=float("nan"), fy=500, cx=320, cy=240, baseline=0.1)


def test_image_size_checks():
    calib = StereoCalibration(fx=500, fy=500, cx=320, cy=240, baseline=0.1, width=640, height=480)
    calib.check_image_size(640, 480)
    with pytest.raises(InputError, match="640 × 480"):
        calib.check_image_size(320, 240)
    unsized = StereoCalibration(fx=500, fy=500, cx=320, cy=240, baseline=0.1)
    with pytest.raises(InputError, match="outside"):
        unsized.check_image_size(200, 150)


def test_scaled_follows_pixel_centres():
    calib = StereoCalibration(fx=500, fy=480, cx=319.5, cy=239.5, baseline=0.1, doffs=4.0,
                              width=640, height=480)
    half = calib.scaled(0.5)
    point = np.array([0.7, -0.3, 6.0])
    u = calib.fx * point[0] / point[2] + calib.cx
    u_half = half.fx * point[0] / point[2] + half.cx
    assert u_half == pytest.approx((u + 0.5) * 0.5 - 0.5)
    assert (half.width, half.height) == (320, 240)
    # the same depth gives half the disparity
    assert half.disparity_from_depth(6.0) == pytest.approx(calib.disparity_from_depth(6.0) / 2)
