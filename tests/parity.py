"""Settings and helpers shared by the parity tests (in-process vs multi-process vs replay)."""

from common.settings import MotionCueSettings, ScaleSettings, SegmentRegistration, TemplateAdaptation, profile_for


def parity_settings(src, seed=3):
    """Every per-frame mechanism on, on the synthetic scene: stabilised (replacing its homography),
    upsampled about 1.3x with the scale search, the template adapted on every confident frame, the
    moving-target cue on the stabilised frames, the template re-registered on the car's segment
    every 0.2 s whatever its score."""
    box = src.frame(0).truth.box
    return profile_for(src, seed=seed, particles=100).model_copy(update={
        "stabilise": "on",
        "scale": ScaleSettings(mode="search", target_size_px=1.3 * max(box[2], box[3])),
        "adaptation": TemplateAdaptation(enabled=True, min_p_visible=0.5, min_score=0.3, interval_s=0.0),
        "compensate_camera_rotation": True,
        "motion_cue": MotionCueSettings(enabled=True),
        "segment": SegmentRegistration(enabled=True, interval_s=0.2, score_quantile=1.0)})


def rewrite_mcap(src_path, dst_path, edit) -> None:
    """Copy an MCAP file, every message's data through ``edit(topic, data) -> data``."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(src_path, "rb") as fh, open(dst_path, "wb") as out:
        reader = make_reader(fh)
        w = Writer(out)
        w.start()
        schemas, channels = {}, {}
        for m in reader.iter_metadata():
            w.add_metadata(m.name, dict(m.metadata))
        for schema, ch, msg in reader.iter_messages(log_time_order=False):
            sid = 0
            if schema is not None:
                sid = schemas.get(schema.id) or schemas.setdefault(
                    schema.id, w.register_schema(schema.name, schema.encoding, schema.data))
            cid = channels.get(ch.id) or channels.setdefault(
                ch.id, w.register_channel(ch.topic, ch.message_encoding, sid))
            w.add_message(cid, msg.log_time, edit(ch.topic, msg.data), msg.publish_time, msg.sequence)
        w.finish()
