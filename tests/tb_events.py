"""Read TensorBoard event files back without TensorBoard: raw TFRecords parsed with tensorboardX.proto."""

import pathlib
import struct


def read_scalars(log_dir: pathlib.Path) -> dict[str, dict[int, float]]:
    """{tag: {step: value}} of every event file in `log_dir` in name order (oldest first), as TensorBoard
    shows them: a session start with a purge step hides the earlier events at or after that step."""
    from tensorboardX.proto import event_pb2

    events = []
    for path in sorted(pathlib.Path(log_dir).glob("events.out.tfevents.*")):
        data = path.read_bytes()
        offset = 0
        while offset < len(data):  # a record: u64 length, u32 crc, payload, u32 crc
            (length,) = struct.unpack_from("<Q", data, offset)
            event = event_pb2.Event()
            event.ParseFromString(data[offset + 12:offset + 12 + length])
            events.append(event)
            offset += 12 + length + 4
    scalars: dict[str, dict[int, float]] = {}
    for event in events:
        if event.HasField("session_log") and event.session_log.status == event_pb2.SessionLog.START:
            for values in scalars.values():
                for step in [s for s in values if s >= event.step]:
                    del values[step]
        for value in event.summary.value:
            scalars.setdefault(value.tag, {})[event.step] = value.simple_value
    return scalars
