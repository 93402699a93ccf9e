"""VP9 frames that decode with errors, told by the reference decoder.

FFmpeg's own VP9 decoder flags no damaged frame: a few flipped bytes inside a frame's data decode to smeared
pictures without an error (0 of 40 measured 2-byte flips flagged). libvpx, VP9's reference decoder, which
PyAV's FFmpeg also holds, refuses such a frame (``Failed to decode tile data``, ``Invalid frame marker``: 80
of 80 measured flips, on two clips) and none of 579 frames of 13 clean sequences. :class:`Vp9Check` feeds the
packets FFmpeg's decoder reads to libvpx as well, only to be told which it refuses: the frames shown are
FFmpeg's, as before, its concealment filling in what is damaged.

After a refusal libvpx refuses every frame until the next key frame (``Keyframe / intra-only frame required``):
those carry the damaged frame's errors as they are decoded from it, and are not flagged, as an H.264 frame
decoded from a flagged one is not; a second damaged frame before that key frame is not told. HEVC has no
such check: FFmpeg holds no other HEVC decoder, and its own logs an error for 3 of 40 such flips.
"""

from __future__ import annotations

from typing import Iterable, Iterator

__all__ = ["Vp9Check"]

#: Pixel formats of VP9's 8-bit profiles, which every libvpx decodes (a libvpx built without high bit depth,
#: as PyAV's is, refuses a 10- or 12-bit stream whole: those are not checked).
CHECKED = frozenset({"yuv420p", "yuv422p", "yuv440p", "yuv444p", "gbrp"})


class Vp9Check:
    """The presentation times of the packets of ``stream`` (an ``av`` video stream) that libvpx refuses, each
    the first refused after a frame it decoded; for a stream that is not 8-bit VP9, or a PyAV without libvpx,
    none."""

    def __init__(self, stream) -> None:
        import av

        context = stream.codec_context
        checked = context.name == "vp9" and context.pix_fmt in CHECKED and "libvpx-vp9" in av.codecs_available
        self.decoder = av.CodecContext.create("libvpx-vp9", "r") if checked else None
        self.refused: set[int] = set()
        self.waiting = False  # refusing every frame since the last refused, until a key frame

    def packets(self, packets: Iterable) -> Iterator:
        """``packets`` as they come, each decoded by libvpx too before it is passed on."""
        import av

        for packet in packets:
            if self.decoder is not None and packet.size:
                try:
                    self.decoder.decode(packet)
                    self.waiting = False
                except av.InvalidDataError:
                    if not self.waiting and packet.pts is not None:
                        self.refused.add(packet.pts)
                    self.waiting = True
            yield packet

    def damaged(self, frame) -> bool:
        """Whether libvpx refused the packet of ``frame`` (an ``av.VideoFrame`` FFmpeg decoded from it)."""
        return frame.pts is not None and frame.pts in self.refused
