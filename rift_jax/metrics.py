"""The paper's metrics: m-SSIM, m-COS and t-IoU of scenes, p-RMSE of unseen-viewpoint signals;
and point scatterers scored as detections (`match_points`)."""

from ._metrics import m_cos as m_cos
from ._metrics import m_ssim as m_ssim
from ._metrics import match_points as match_points
from ._metrics import p_rmse as p_rmse
from ._metrics import t_iou as t_iou

__all__ = ["m_ssim", "m_cos", "t_iou", "p_rmse", "match_points"]
