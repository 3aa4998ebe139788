"""The simulated beacon channel and recorder.

``atmosphere`` (speed of sound, ISO 9613-1 absorption, Maekawa loss, reflection),
``channel`` (geometric paths among the yard's boxes), ``chirp`` (waveform and TDMA
schedule), ``synthesis`` (one chirp through its channel, ambient noise),
``stream`` (writes ``audio.wav``).
"""

__all__ = ["atmosphere", "channel", "chirp", "synthesis", "stream"]
