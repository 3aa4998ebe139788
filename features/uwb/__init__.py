"""UWB tag logs: ``reader`` reads ``uwb.csv`` (two-way ranges and PDoA angles of arrival per anchor);
``position`` turns each ranging round into a horizontal position with its covariance."""

__all__ = ["reader", "position"]
