from google.protobuf import struct_pb2 as _struct_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class Truth(_message.Message):
    __slots__ = ("visible", "box_x", "box_y", "box_w", "box_h", "centre_x", "centre_y", "angle_deg", "visible_fraction")
    VISIBLE_FIELD_NUMBER: _ClassVar[int]
    BOX_X_FIELD_NUMBER: _ClassVar[int]
    BOX_Y_FIELD_NUMBER: _ClassVar[int]
    BOX_W_FIELD_NUMBER: _ClassVar[int]
    BOX_H_FIELD_NUMBER: _ClassVar[int]
    CENTRE_X_FIELD_NUMBER: _ClassVar[int]
    CENTRE_Y_FIELD_NUMBER: _ClassVar[int]
    ANGLE_DEG_FIELD_NUMBER: _ClassVar[int]
    VISIBLE_FRACTION_FIELD_NUMBER: _ClassVar[int]
    visible: bool
    box_x: float
    box_y: float
    box_w: float
    box_h: float
    centre_x: float
    centre_y: float
    angle_deg: float
    visible_fraction: float
    def __init__(self, visible: _Optional[bool] = ..., box_x: _Optional[float] = ..., box_y: _Optional[float] = ..., box_w: _Optional[float] = ..., box_h: _Optional[float] = ..., centre_x: _Optional[float] = ..., centre_y: _Optional[float] = ..., angle_deg: _Optional[float] = ..., visible_fraction: _Optional[float] = ...) -> None: ...

class FrameInfo(_message.Message):
    __slots__ = ("index", "time_s", "capture_ns", "width", "height", "homography", "truth", "source", "end_of_stream", "total_frames", "truth_people", "truth_parts")
    INDEX_FIELD_NUMBER: _ClassVar[int]
    TIME_S_FIELD_NUMBER: _ClassVar[int]
    CAPTURE_NS_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    HOMOGRAPHY_FIELD_NUMBER: _ClassVar[int]
    TRUTH_FIELD_NUMBER: _ClassVar[int]
    SOURCE_FIELD_NUMBER: _ClassVar[int]
    END_OF_STREAM_FIELD_NUMBER: _ClassVar[int]
    TOTAL_FRAMES_FIELD_NUMBER: _ClassVar[int]
    TRUTH_PEOPLE_FIELD_NUMBER: _ClassVar[int]
    TRUTH_PARTS_FIELD_NUMBER: _ClassVar[int]
    index: int
    time_s: float
    capture_ns: int
    width: int
    height: int
    homography: _containers.RepeatedScalarFieldContainer[float]
    truth: Truth
    source: str
    end_of_stream: bool
    total_frames: int
    truth_people: int
    truth_parts: bytes
    def __init__(self, index: _Optional[int] = ..., time_s: _Optional[float] = ..., capture_ns: _Optional[int] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., homography: _Optional[_Iterable[float]] = ..., truth: _Optional[_Union[Truth, _Mapping]] = ..., source: _Optional[str] = ..., end_of_stream: _Optional[bool] = ..., total_frames: _Optional[int] = ..., truth_people: _Optional[int] = ..., truth_parts: _Optional[bytes] = ...) -> None: ...

class ScoreQuery(_message.Message):
    __slots__ = ("request_id", "client", "frame_index", "kind", "count", "hypotheses", "template_version", "factor", "one_off", "histogram_json", "reference_count", "bins", "references", "ref_index", "crop")
    class Kind(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        AT: _ClassVar[ScoreQuery.Kind]
        GRID: _ClassVar[ScoreQuery.Kind]
        TEMPLATE: _ClassVar[ScoreQuery.Kind]
        PEAK: _ClassVar[ScoreQuery.Kind]
        HISTOGRAMS: _ClassVar[ScoreQuery.Kind]
        SIMILARITY: _ClassVar[ScoreQuery.Kind]
    AT: ScoreQuery.Kind
    GRID: ScoreQuery.Kind
    TEMPLATE: ScoreQuery.Kind
    PEAK: ScoreQuery.Kind
    HISTOGRAMS: ScoreQuery.Kind
    SIMILARITY: ScoreQuery.Kind
    REQUEST_ID_FIELD_NUMBER: _ClassVar[int]
    CLIENT_FIELD_NUMBER: _ClassVar[int]
    FRAME_INDEX_FIELD_NUMBER: _ClassVar[int]
    KIND_FIELD_NUMBER: _ClassVar[int]
    COUNT_FIELD_NUMBER: _ClassVar[int]
    HYPOTHESES_FIELD_NUMBER: _ClassVar[int]
    TEMPLATE_VERSION_FIELD_NUMBER: _ClassVar[int]
    FACTOR_FIELD_NUMBER: _ClassVar[int]
    ONE_OFF_FIELD_NUMBER: _ClassVar[int]
    HISTOGRAM_JSON_FIELD_NUMBER: _ClassVar[int]
    REFERENCE_COUNT_FIELD_NUMBER: _ClassVar[int]
    BINS_FIELD_NUMBER: _ClassVar[int]
    REFERENCES_FIELD_NUMBER: _ClassVar[int]
    REF_INDEX_FIELD_NUMBER: _ClassVar[int]
    CROP_FIELD_NUMBER: _ClassVar[int]
    request_id: int
    client: str
    frame_index: int
    kind: ScoreQuery.Kind
    count: int
    hypotheses: bytes
    template_version: int
    factor: float
    one_off: bool
    histogram_json: str
    reference_count: int
    bins: int
    references: bytes
    ref_index: bytes
    crop: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, request_id: _Optional[int] = ..., client: _Optional[str] = ..., frame_index: _Optional[int] = ..., kind: _Optional[_Union[ScoreQuery.Kind, str]] = ..., count: _Optional[int] = ..., hypotheses: _Optional[bytes] = ..., template_version: _Optional[int] = ..., factor: _Optional[float] = ..., one_off: _Optional[bool] = ..., histogram_json: _Optional[str] = ..., reference_count: _Optional[int] = ..., bins: _Optional[int] = ..., references: _Optional[bytes] = ..., ref_index: _Optional[bytes] = ..., crop: _Optional[_Iterable[float]] = ...) -> None: ...

class ScoreReply(_message.Message):
    __slots__ = ("request_id", "client", "frame_index", "status", "error", "count", "angles", "scores", "valid", "template", "prepare_ms", "score_ms", "pmatrix", "pmatrix_columns", "dtype", "bins")
    class Status(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        OK: _ClassVar[ScoreReply.Status]
        UNKNOWN_FRAME: _ClassVar[ScoreReply.Status]
        BAD_REQUEST: _ClassVar[ScoreReply.Status]
        NO_TEMPLATE: _ClassVar[ScoreReply.Status]
        INTERNAL_ERROR: _ClassVar[ScoreReply.Status]
    OK: ScoreReply.Status
    UNKNOWN_FRAME: ScoreReply.Status
    BAD_REQUEST: ScoreReply.Status
    NO_TEMPLATE: ScoreReply.Status
    INTERNAL_ERROR: ScoreReply.Status
    REQUEST_ID_FIELD_NUMBER: _ClassVar[int]
    CLIENT_FIELD_NUMBER: _ClassVar[int]
    FRAME_INDEX_FIELD_NUMBER: _ClassVar[int]
    STATUS_FIELD_NUMBER: _ClassVar[int]
    ERROR_FIELD_NUMBER: _ClassVar[int]
    COUNT_FIELD_NUMBER: _ClassVar[int]
    ANGLES_FIELD_NUMBER: _ClassVar[int]
    SCORES_FIELD_NUMBER: _ClassVar[int]
    VALID_FIELD_NUMBER: _ClassVar[int]
    TEMPLATE_FIELD_NUMBER: _ClassVar[int]
    PREPARE_MS_FIELD_NUMBER: _ClassVar[int]
    SCORE_MS_FIELD_NUMBER: _ClassVar[int]
    PMATRIX_FIELD_NUMBER: _ClassVar[int]
    PMATRIX_COLUMNS_FIELD_NUMBER: _ClassVar[int]
    DTYPE_FIELD_NUMBER: _ClassVar[int]
    BINS_FIELD_NUMBER: _ClassVar[int]
    request_id: int
    client: str
    frame_index: int
    status: ScoreReply.Status
    error: str
    count: int
    angles: int
    scores: bytes
    valid: bytes
    template: Template
    prepare_ms: float
    score_ms: float
    pmatrix: bytes
    pmatrix_columns: int
    dtype: str
    bins: int
    def __init__(self, request_id: _Optional[int] = ..., client: _Optional[str] = ..., frame_index: _Optional[int] = ..., status: _Optional[_Union[ScoreReply.Status, str]] = ..., error: _Optional[str] = ..., count: _Optional[int] = ..., angles: _Optional[int] = ..., scores: _Optional[bytes] = ..., valid: _Optional[bytes] = ..., template: _Optional[_Union[Template, _Mapping]] = ..., prepare_ms: _Optional[float] = ..., score_ms: _Optional[float] = ..., pmatrix: _Optional[bytes] = ..., pmatrix_columns: _Optional[int] = ..., dtype: _Optional[str] = ..., bins: _Optional[int] = ...) -> None: ...

class Template(_message.Message):
    __slots__ = ("version", "rows", "columns", "pmatrix", "centre_x", "centre_y", "box", "frame_index")
    VERSION_FIELD_NUMBER: _ClassVar[int]
    ROWS_FIELD_NUMBER: _ClassVar[int]
    COLUMNS_FIELD_NUMBER: _ClassVar[int]
    PMATRIX_FIELD_NUMBER: _ClassVar[int]
    CENTRE_X_FIELD_NUMBER: _ClassVar[int]
    CENTRE_Y_FIELD_NUMBER: _ClassVar[int]
    BOX_FIELD_NUMBER: _ClassVar[int]
    FRAME_INDEX_FIELD_NUMBER: _ClassVar[int]
    version: int
    rows: int
    columns: int
    pmatrix: bytes
    centre_x: float
    centre_y: float
    box: _containers.RepeatedScalarFieldContainer[float]
    frame_index: int
    def __init__(self, version: _Optional[int] = ..., rows: _Optional[int] = ..., columns: _Optional[int] = ..., pmatrix: _Optional[bytes] = ..., centre_x: _Optional[float] = ..., centre_y: _Optional[float] = ..., box: _Optional[_Iterable[float]] = ..., frame_index: _Optional[int] = ...) -> None: ...

class Estimate(_message.Message):
    __slots__ = ("frame_index", "time_s", "observed", "filter", "x", "y", "theta_deg", "p_visible", "world_x", "world_y", "vx", "vy", "speed", "mmse_x", "mmse_y", "n_eff", "resampled", "frames_skipped", "step_ms", "latency_ms", "w", "h", "reacquired", "box_dx", "box_dy")
    FRAME_INDEX_FIELD_NUMBER: _ClassVar[int]
    TIME_S_FIELD_NUMBER: _ClassVar[int]
    OBSERVED_FIELD_NUMBER: _ClassVar[int]
    FILTER_FIELD_NUMBER: _ClassVar[int]
    X_FIELD_NUMBER: _ClassVar[int]
    Y_FIELD_NUMBER: _ClassVar[int]
    THETA_DEG_FIELD_NUMBER: _ClassVar[int]
    P_VISIBLE_FIELD_NUMBER: _ClassVar[int]
    WORLD_X_FIELD_NUMBER: _ClassVar[int]
    WORLD_Y_FIELD_NUMBER: _ClassVar[int]
    VX_FIELD_NUMBER: _ClassVar[int]
    VY_FIELD_NUMBER: _ClassVar[int]
    SPEED_FIELD_NUMBER: _ClassVar[int]
    MMSE_X_FIELD_NUMBER: _ClassVar[int]
    MMSE_Y_FIELD_NUMBER: _ClassVar[int]
    N_EFF_FIELD_NUMBER: _ClassVar[int]
    RESAMPLED_FIELD_NUMBER: _ClassVar[int]
    FRAMES_SKIPPED_FIELD_NUMBER: _ClassVar[int]
    STEP_MS_FIELD_NUMBER: _ClassVar[int]
    LATENCY_MS_FIELD_NUMBER: _ClassVar[int]
    W_FIELD_NUMBER: _ClassVar[int]
    H_FIELD_NUMBER: _ClassVar[int]
    REACQUIRED_FIELD_NUMBER: _ClassVar[int]
    BOX_DX_FIELD_NUMBER: _ClassVar[int]
    BOX_DY_FIELD_NUMBER: _ClassVar[int]
    frame_index: int
    time_s: float
    observed: bool
    filter: str
    x: float
    y: float
    theta_deg: float
    p_visible: float
    world_x: float
    world_y: float
    vx: float
    vy: float
    speed: float
    mmse_x: float
    mmse_y: float
    n_eff: float
    resampled: bool
    frames_skipped: int
    step_ms: float
    latency_ms: float
    w: float
    h: float
    reacquired: bool
    box_dx: float
    box_dy: float
    def __init__(self, frame_index: _Optional[int] = ..., time_s: _Optional[float] = ..., observed: _Optional[bool] = ..., filter: _Optional[str] = ..., x: _Optional[float] = ..., y: _Optional[float] = ..., theta_deg: _Optional[float] = ..., p_visible: _Optional[float] = ..., world_x: _Optional[float] = ..., world_y: _Optional[float] = ..., vx: _Optional[float] = ..., vy: _Optional[float] = ..., speed: _Optional[float] = ..., mmse_x: _Optional[float] = ..., mmse_y: _Optional[float] = ..., n_eff: _Optional[float] = ..., resampled: _Optional[bool] = ..., frames_skipped: _Optional[int] = ..., step_ms: _Optional[float] = ..., latency_ms: _Optional[float] = ..., w: _Optional[float] = ..., h: _Optional[float] = ..., reacquired: _Optional[bool] = ..., box_dx: _Optional[float] = ..., box_dy: _Optional[float] = ...) -> None: ...

class MultiEstimate(_message.Message):
    __slots__ = ("frame_index", "time_s", "filter", "targets", "parts", "part_names", "positions", "velocities", "n_eff", "moved", "units", "gate_area", "n_measurements", "acceptance", "parents", "observed", "step_ms", "latency_ms", "frames_skipped")
    class AcceptanceEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: float
        def __init__(self, key: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...
    FRAME_INDEX_FIELD_NUMBER: _ClassVar[int]
    TIME_S_FIELD_NUMBER: _ClassVar[int]
    FILTER_FIELD_NUMBER: _ClassVar[int]
    TARGETS_FIELD_NUMBER: _ClassVar[int]
    PARTS_FIELD_NUMBER: _ClassVar[int]
    PART_NAMES_FIELD_NUMBER: _ClassVar[int]
    POSITIONS_FIELD_NUMBER: _ClassVar[int]
    VELOCITIES_FIELD_NUMBER: _ClassVar[int]
    N_EFF_FIELD_NUMBER: _ClassVar[int]
    MOVED_FIELD_NUMBER: _ClassVar[int]
    UNITS_FIELD_NUMBER: _ClassVar[int]
    GATE_AREA_FIELD_NUMBER: _ClassVar[int]
    N_MEASUREMENTS_FIELD_NUMBER: _ClassVar[int]
    ACCEPTANCE_FIELD_NUMBER: _ClassVar[int]
    PARENTS_FIELD_NUMBER: _ClassVar[int]
    OBSERVED_FIELD_NUMBER: _ClassVar[int]
    STEP_MS_FIELD_NUMBER: _ClassVar[int]
    LATENCY_MS_FIELD_NUMBER: _ClassVar[int]
    FRAMES_SKIPPED_FIELD_NUMBER: _ClassVar[int]
    frame_index: int
    time_s: float
    filter: str
    targets: int
    parts: int
    part_names: _containers.RepeatedScalarFieldContainer[str]
    positions: bytes
    velocities: bytes
    n_eff: bytes
    moved: bytes
    units: int
    gate_area: bytes
    n_measurements: bytes
    acceptance: _containers.ScalarMap[str, float]
    parents: bytes
    observed: bool
    step_ms: float
    latency_ms: float
    frames_skipped: int
    def __init__(self, frame_index: _Optional[int] = ..., time_s: _Optional[float] = ..., filter: _Optional[str] = ..., targets: _Optional[int] = ..., parts: _Optional[int] = ..., part_names: _Optional[_Iterable[str]] = ..., positions: _Optional[bytes] = ..., velocities: _Optional[bytes] = ..., n_eff: _Optional[bytes] = ..., moved: _Optional[bytes] = ..., units: _Optional[int] = ..., gate_area: _Optional[bytes] = ..., n_measurements: _Optional[bytes] = ..., acceptance: _Optional[_Mapping[str, float]] = ..., parents: _Optional[bytes] = ..., observed: _Optional[bool] = ..., step_ms: _Optional[float] = ..., latency_ms: _Optional[float] = ..., frames_skipped: _Optional[int] = ...) -> None: ...

class ParticleCloud(_message.Message):
    __slots__ = ("frame_index", "time_s", "count", "particles", "image_xy", "weights", "p_visible")
    FRAME_INDEX_FIELD_NUMBER: _ClassVar[int]
    TIME_S_FIELD_NUMBER: _ClassVar[int]
    COUNT_FIELD_NUMBER: _ClassVar[int]
    PARTICLES_FIELD_NUMBER: _ClassVar[int]
    IMAGE_XY_FIELD_NUMBER: _ClassVar[int]
    WEIGHTS_FIELD_NUMBER: _ClassVar[int]
    P_VISIBLE_FIELD_NUMBER: _ClassVar[int]
    frame_index: int
    time_s: float
    count: int
    particles: bytes
    image_xy: bytes
    weights: bytes
    p_visible: bytes
    def __init__(self, frame_index: _Optional[int] = ..., time_s: _Optional[float] = ..., count: _Optional[int] = ..., particles: _Optional[bytes] = ..., image_xy: _Optional[bytes] = ..., weights: _Optional[bytes] = ..., p_visible: _Optional[bytes] = ...) -> None: ...

class RunConfig(_message.Message):
    __slots__ = ("run_id", "source", "init_box", "seed", "start_ns", "pace", "settings", "versions", "multi", "settings_json", "versions_json", "multi_json")
    class VersionsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: str
        def __init__(self, key: _Optional[str] = ..., value: _Optional[str] = ...) -> None: ...
    RUN_ID_FIELD_NUMBER: _ClassVar[int]
    SOURCE_FIELD_NUMBER: _ClassVar[int]
    INIT_BOX_FIELD_NUMBER: _ClassVar[int]
    SEED_FIELD_NUMBER: _ClassVar[int]
    START_NS_FIELD_NUMBER: _ClassVar[int]
    PACE_FIELD_NUMBER: _ClassVar[int]
    SETTINGS_FIELD_NUMBER: _ClassVar[int]
    VERSIONS_FIELD_NUMBER: _ClassVar[int]
    MULTI_FIELD_NUMBER: _ClassVar[int]
    SETTINGS_JSON_FIELD_NUMBER: _ClassVar[int]
    VERSIONS_JSON_FIELD_NUMBER: _ClassVar[int]
    MULTI_JSON_FIELD_NUMBER: _ClassVar[int]
    run_id: str
    source: str
    init_box: _containers.RepeatedScalarFieldContainer[float]
    seed: int
    start_ns: int
    pace: str
    settings: _struct_pb2.Struct
    versions: _containers.ScalarMap[str, str]
    multi: _struct_pb2.Struct
    settings_json: str
    versions_json: str
    multi_json: str
    def __init__(self, run_id: _Optional[str] = ..., source: _Optional[str] = ..., init_box: _Optional[_Iterable[float]] = ..., seed: _Optional[int] = ..., start_ns: _Optional[int] = ..., pace: _Optional[str] = ..., settings: _Optional[_Union[_struct_pb2.Struct, _Mapping]] = ..., versions: _Optional[_Mapping[str, str]] = ..., multi: _Optional[_Union[_struct_pb2.Struct, _Mapping]] = ..., settings_json: _Optional[str] = ..., versions_json: _Optional[str] = ..., multi_json: _Optional[str] = ...) -> None: ...

class ServiceStatus(_message.Message):
    __slots__ = ("service", "received", "published", "malformed", "dropped", "errors", "cpu_s", "final")
    SERVICE_FIELD_NUMBER: _ClassVar[int]
    RECEIVED_FIELD_NUMBER: _ClassVar[int]
    PUBLISHED_FIELD_NUMBER: _ClassVar[int]
    MALFORMED_FIELD_NUMBER: _ClassVar[int]
    DROPPED_FIELD_NUMBER: _ClassVar[int]
    ERRORS_FIELD_NUMBER: _ClassVar[int]
    CPU_S_FIELD_NUMBER: _ClassVar[int]
    FINAL_FIELD_NUMBER: _ClassVar[int]
    service: str
    received: int
    published: int
    malformed: int
    dropped: int
    errors: int
    cpu_s: float
    final: bool
    def __init__(self, service: _Optional[str] = ..., received: _Optional[int] = ..., published: _Optional[int] = ..., malformed: _Optional[int] = ..., dropped: _Optional[int] = ..., errors: _Optional[int] = ..., cpu_s: _Optional[float] = ..., final: _Optional[bool] = ...) -> None: ...
