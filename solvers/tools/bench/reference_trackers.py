"""Plain references the project's tracker and flow are compared with (``bench --accuracy`` and the
accuracy tests): textbook OpenCV calls, kept independent of the project's own video code."""

import numpy as np


def _gray_frames(path):
    import cv2  # OpenCV: imported on first use (not every caller of the tools has it)

    cap, frames = cv2.VideoCapture(str(path)), []
    while (got := cap.read())[0]:
        frames.append(cv2.cvtColor(got[1], cv2.COLOR_BGR2GRAY))
    cap.release()
    return frames


def plain_lk(path, seeds, reference=1, win=21, levels=3):
    """Textbook pyramidal LK with per-frame re-registration: LK from the previous frame, then from
    the reference frame's patch started there. (F, M, 2), NaN where LK's status fails; frames from
    ``reference`` (1 = the first frame) on."""
    import cv2  # OpenCV: imported on first use

    frames = _gray_frames(path)
    ref, crit = reference - 1, (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
    p0 = np.float32(seeds).reshape(-1, 1, 2)
    out = np.full((len(frames), len(seeds), 2), np.nan)
    prev, pts = frames[ref], p0
    for t in range(ref, len(frames)):
        cont = cv2.calcOpticalFlowPyrLK(prev, frames[t], pts, None, winSize=(win, win), maxLevel=levels, criteria=crit)[0]
        new, st, _ = cv2.calcOpticalFlowPyrLK(frames[ref], frames[t], p0, cont.copy(), winSize=(win, win),
                                              maxLevel=levels, criteria=crit, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        out[t] = np.where(st.reshape(-1, 1) == 1, new.reshape(-1, 2), np.nan)
        prev, pts = frames[t], np.where(st.reshape(-1, 1, 1) == 1, new, cont).astype(np.float32)
    return out


def plain_dis(path, reference=1):
    """Plain DIS (OpenCV's fast preset refined to half resolution, as the project's default) from the
    reference frame to every frame: (F, H, W, 2)."""
    import cv2  # OpenCV: imported on first use

    frames = _gray_frames(path)
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_FAST)
    dis.setFinestScale(1)
    return np.stack([dis.calc(frames[reference - 1], f, None) for f in frames])
