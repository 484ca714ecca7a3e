"""``mr-suspension bag repair``: bags a crash left open are made readable, nothing else changes.

The crash images are what a killed writer leaves on disk: the storage file as it was after its
last flush (copied before the writer closes it). The expected recoveries come from the ``mcap``
library's index of the intact file, not from the repair code.
"""

import hashlib
import math
import shutil

from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores

from mr_suspension import bagtools, cli
from mr_suspension.identification.data import load_records

STORE = get_typestore(Stores.LATEST)
FLOAT = 'std_msgs/msg/Float64'
JOINT = 'sensor_msgs/msg/JointState'
T0 = 1_700_000_000 * 10**9  # log times: T0 + k ms
MS = 1_000_000


def float_msg(value):
    return STORE.serialize_cdr(STORE.types[FLOAT](data=float(value)), FLOAT)


def add(writer, topic, msgtype):
    msgdef, _ = STORE.generate_msgdef(msgtype, ros_version=2)
    return writer.add_connection(topic, msgtype, msgdef, STORE.hash_rihs01(msgtype))


def write_counter(path, storage, n, flush_at=None, flush_period=0.05):
    """Bag with messages 0..n-1 on /a (and every other one on /b); return the crash image.

    The crash image is the storage file's bytes after the flush that follows message
    ``flush_at`` (None: no image).
    """
    writer = bagtools.BagWriter(path, storage, flush_period=flush_period, metadata_period=0.1)
    a = add(writer, '/a', FLOAT)
    b = add(writer, '/b', FLOAT)
    image = None
    for k in range(n):
        writer.write(a, T0 + k * MS, float_msg(k))
        if k % 2 == 0:
            writer.write(b, T0 + k * MS, float_msg(-k))
        if k == flush_at:
            writer.flush()
            image = {p.name: p.read_bytes() for p in path.iterdir() if p.suffix != '.yaml'}
    writer.close()
    return image


def read_values(bag):
    """``{topic: [(log time, value)]}`` read with rosbags (raises if unreadable)."""
    out = {}
    with Reader(bag) as reader:
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t, STORE.deserialize_cdr(raw, FLOAT).data))
        assert reader.message_count == sum(len(v) for v in out.values())
    return out


def complete_chunks(path):
    """``[(chunk end offset, {topic: messages})]`` from the intact file's own index."""
    out = []
    with open(path, 'rb') as fh:
        summary = make_reader(fh).get_summary()
        for chunk in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            counts = {}
            for cid, offset in chunk.message_index_offsets.items():
                fh.seek(offset)
                index = next(StreamReader(fh, skip_magic=True).records)
                counts[summary.channels[cid].topic] = len(index.records)
            out.append((chunk.chunk_start_offset, chunk.chunk_length, counts))
    return out, len(summary.chunk_indexes)


def digest(folder):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


def test_truncated_mcap_recovers_every_complete_chunk(tmp_path):
    """Cut at many byte offsets (header, mid-chunk, chunk ends, summary): complete chunks kept."""
    src = tmp_path / 'src'
    write_counter(src, 'mcap', 600, flush_period=0.05)
    data = (src / 'src.mcap').read_bytes()
    chunks, n = complete_chunks(src / 'src.mcap')
    assert n >= 10  # 0.6 s of log time flushed every 0.05 s
    cuts = [0, 5, 8, 40, chunks[0][0] + 3]
    for start, length, _ in chunks[::3]:
        cuts += [start + length // 2, start + length - 1, start + length]
    cuts += [len(data) - 300, len(data) - 20, len(data) - 1]  # in the summary section
    for cut in cuts:
        bag = tmp_path / f'cut{cut}'
        bag.mkdir()
        shutil.copy(src / 'metadata.yaml', bag)
        (bag / f'cut{cut}.mcap').write_bytes(data[:cut])
        n_a = sum(c.get('/a', 0) for s, n, c in chunks if s + n <= cut)
        n_b = sum(c.get('/b', 0) for s, n, c in chunks if s + n <= cut)
        lines = []
        res = bagtools.repair(bag, log=lines.append)
        got = read_values(bag) if n_a + n_b else {}
        assert [v for _, v in got.get('/a', [])] == [float(k) for k in range(n_a)], cut
        assert [v for _, v in got.get('/b', [])] == [-2.0 * k for k in range(n_b)], cut
        assert res['messages'] == n_a + n_b
        # The original is kept byte for byte; a second repair changes nothing.
        assert (bag / f'cut{cut}.mcap.orig').read_bytes() == data[:cut]
        before = digest(bag)
        again = bagtools.repair(bag, log=lines.append)
        assert again['metadata'] == 'kept' and again['files'][0]['state'] == 'ok'
        assert digest(bag) == before
        assert all('\n' not in line for line in lines)


def test_crash_image_repaired_in_place_and_to_out(tmp_path):
    src = tmp_path / 'src'
    image = write_counter(src, 'mcap', 400, flush_at=250)
    bag = tmp_path / 'crashed'
    bag.mkdir()
    (bag / 'crashed.mcap').write_bytes(image['src.mcap'])
    with pytest.raises(Exception):
        Reader(bag).open()  # no metadata.yaml, no summary: unreadable before the repair
    out = tmp_path / 'fixed'
    before = digest(bag)
    assert cli.main(['bag', 'repair', str(bag), '--out', str(out)]) == 0
    assert digest(bag) == before  # --out leaves the bag alone
    got = read_values(out)
    assert [v for _, v in got['/a']] == [float(k) for k in range(251)]
    assert [t for t, _ in got['/a']] == [T0 + k * MS for k in range(251)]
    bagtools.repair(bag, log=lambda _: None)
    assert read_values(bag) == got


@pytest.mark.parametrize('content', ['', 'rosbag2_bagfile_information: [not, a, mapping',
                                     'just text', None])
def test_bad_metadata_of_healthy_bag_is_rebuilt(tmp_path, content):
    bag = tmp_path / 'bag'
    write_counter(bag, 'mcap', 300)
    reference = (bag / 'metadata.yaml').read_text()
    if content is None:
        (bag / 'metadata.yaml').unlink()
    else:
        (bag / 'metadata.yaml').write_text(content)
    mcap_bytes = (bag / 'bag.mcap').read_bytes()
    res = bagtools.repair(bag, log=lambda _: None)
    assert res['metadata'] == 'rebuilt' and res['files'][0]['state'] == 'ok'
    assert (bag / 'bag.mcap').read_bytes() == mcap_bytes  # a healthy file is not rewritten
    assert (bag / 'metadata.yaml').read_text() == reference  # what the writer wrote at close
    got = read_values(bag)
    assert len(got['/a']) == 300 and len(got['/b']) == 150
    if content and content.strip():
        assert (bag / 'metadata.yaml.orig').read_text() == content


def test_sqlite3_crash_image_and_missing_metadata(tmp_path):
    src = tmp_path / 'src'
    image = write_counter(src, 'sqlite3', 400, flush_at=199)
    assert 'src.db3-wal' in image  # committed data waits in the write-ahead log
    bag = tmp_path / 'crashed'
    bag.mkdir()
    for name, data in image.items():
        (bag / name.replace('src', 'crashed')).write_bytes(data)
    lines = []
    res = bagtools.repair(bag, log=lines.append)
    assert res['storage'] == 'sqlite3' and res['files'][0]['state'] == 'repaired'
    assert not (bag / 'crashed.db3-wal').exists()
    got = read_values(bag)
    assert [v for _, v in got['/a']] == [float(k) for k in range(200)]
    assert len(got['/b']) == 100
    # The closed bag, its metadata removed: rebuilt, same as the writer's.
    reference = (src / 'metadata.yaml').read_text()
    (src / 'metadata.yaml').unlink()
    bagtools.repair(src, log=lines.append)
    assert (src / 'metadata.yaml').read_text() == reference
    assert len(read_values(src)['/a']) == 400


@pytest.mark.parametrize('setup, message', [
    (lambda p: p.mkdir(), 'no .mcap or .db3 file'),
    (lambda p: None, 'no such bag directory'),
    (lambda p: p.write_text('x'), 'not a directory'),
    (lambda p: (p.mkdir(), (p / 'metadata.yaml').write_text('')), 'no .mcap or .db3 file'),
    (lambda p: (p.mkdir(), (p / 'x.db3').write_text('not sqlite')), 'cannot read as a sqlite3'),
])
def test_not_a_bag_is_a_one_line_error(tmp_path, capsys, setup, message):
    bag = tmp_path / 'thing'
    setup(bag)
    assert cli.main(['bag', 'repair', str(bag)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count('\n') == 1 and 'Traceback' not in err


def test_diagnose_reads_a_repaired_bag(tmp_path):
    """A damper run (stroke, rate, force, command) cut by a crash loads through load_records."""
    bag = tmp_path / 'src'
    writer = bagtools.BagWriter(bag, 'mcap', flush_period=0.1, metadata_period=0.5)
    force = add(writer, '/rig/damper/force', JOINT)
    command = add(writer, '/rig/current_command', FLOAT)
    joint = STORE.types[JOINT]
    header = STORE.types['std_msgs/msg/Header']
    stamp = STORE.types['builtin_interfaces/msg/Time']

    def sample(k):
        t = k * 1e-3
        x = 0.01 * math.sin(2 * math.pi * 2.0 * t)
        v = 0.01 * 2 * math.pi * 2.0 * math.cos(2 * math.pi * 2.0 * t)
        return x, v, 2000.0 * v + 300.0 * math.tanh(v / 0.01)

    image = None
    for k in range(2000):
        x, v, f = sample(k)
        ns = 10**9 + k * MS  # simulated time, as lock-step bags carry
        msg = joint(header=header(stamp=stamp(sec=ns // 10**9, nanosec=ns % 10**9),
                                  frame_id='damper'),
                    name=['stroke'], position=np.array([x]), velocity=np.array([v]),
                    effort=np.array([f]))
        writer.write(force, ns, STORE.serialize_cdr(msg, JOINT))
        writer.write(command, ns, float_msg(1.0))
        if k == 1600:
            writer.flush()
            image = (bag / 'src.mcap').read_bytes()
    writer.close()
    crashed = tmp_path / 'crashed'
    crashed.mkdir()
    (crashed / 'crashed.mcap').write_bytes(image)
    bagtools.repair(crashed, log=lambda _: None)
    (rec,) = load_records([crashed])
    n = rec.time.size
    assert n == 1601
    expected = np.array([sample(k) for k in range(n)])
    assert np.allclose(rec.displacement, expected[:, 0])
    assert np.allclose(rec.force, expected[:, 2])
