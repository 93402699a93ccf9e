"""Test videos written with PyAV."""

from __future__ import annotations


def mux_all(container, stream, frames) -> None:
    """Encode ``frames`` (RGB arrays, or ``av.VideoFrame`` as they are) into ``stream`` of ``container``, muxing every
    packet, the encoder's held ones last."""
    import av

    for frame in frames:
        if not isinstance(frame, av.VideoFrame):
            frame = av.VideoFrame.from_ndarray(frame, format="rgb24")
        for packet in stream.encode(frame):
            container.mux(packet)
    for packet in stream.encode():
        container.mux(packet)
