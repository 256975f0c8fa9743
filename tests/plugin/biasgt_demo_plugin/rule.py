"""A WARN when the recording is shorter than a minute."""


def check(ev) -> list[str]:
    if ev.recording_s is None or ev.recording_s >= 60.0:
        return []
    return [f"the recording lasts {ev.recording_s:.1f} s, less than a minute"]
