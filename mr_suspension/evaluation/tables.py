"""Metric tables: CSV and Markdown, with the change relative to a reference law."""

import csv
import math

COLUMNS = (('body_acc_rms', 'a_s RMS [m/s2]', 1.0), ('body_acc_wk_rms', 'a_wk RMS [m/s2]', 1.0),
           ('vdv', 'VDV [m/s1.75]', 1.0), ('working_space_rms', 'x RMS [mm]', 1e3),
           ('working_space_peak', 'x peak [mm]', 1e3), ('tyre_load_rms', 'dF_t RMS [N]', 1.0),
           ('settling_time', 't_s [s]', 1.0))


def write_csv(rows, path):
    """Write the rows (dicts with the same keys) as CSV."""
    if not rows:
        raise ValueError('write_csv: no rows')
    keys = list(rows[0])
    with open(path, 'w', newline='', encoding='utf-8') as fh:
        writer = csv.DictWriter(fh, fieldnames=keys)
        writer.writeheader()
        for row in rows:
            writer.writerow(row)


def relative(rows, reference='passive_0A', keys=None):
    """Per-scenario change ``(value / reference - 1)`` in % for each metric (new rows)."""
    keys = keys or [c[0] for c in COLUMNS]
    ref = {r['scenario']: r for r in rows if r['law'] == reference}
    out = []
    for row in rows:
        base = ref.get(row['scenario'])
        new = {'law': row['law'], 'scenario': row['scenario']}
        for k in keys:
            b = base.get(k, float('nan')) if base else float('nan')
            v = row.get(k, float('nan'))
            ok = b and math.isfinite(b) and math.isfinite(v)
            new[k] = 100.0 * (v / b - 1.0) if ok else float('nan')
        out.append(new)
    return out


def _fmt(v, scale=1.0, digits=3):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return '-' if v is None or math.isnan(v) else 'inf'
    return f'{v * scale:.{digits}g}'


def markdown(rows, columns=COLUMNS, percent=False):
    """Markdown table of the rows (one line per law and scenario)."""
    head = '| law | scenario | ' + ' | '.join(c[1] if not percent else c[1].split(' [')[0]
                                              + ' [%]' for c in columns) + ' |'
    sep = '|' + '---|' * (len(columns) + 2)
    lines = [head, sep]
    for row in rows:
        cells = []
        for key, _, scale in columns:
            v = row.get(key, float('nan'))
            cells.append(f'{v:+.1f}' if percent and math.isfinite(v) else
                         ('-' if percent else _fmt(v, scale)))
        lines.append(f'| {row["law"]} | {row["scenario"]} | ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines)


def summary_by_law(rows, scenarios=None):
    """Mean of each metric over the chosen scenarios, per law (ISO averages and the like)."""
    out = {}
    for row in rows:
        if scenarios is not None and row['scenario'] not in scenarios:
            continue
        acc = out.setdefault(row['law'], {})
        for key, _, _ in COLUMNS:
            v = row.get(key, float('nan'))
            if isinstance(v, float) and math.isfinite(v):
                acc.setdefault(key, []).append(v)
    return [{'law': law, 'scenario': 'mean', **{k: sum(v) / len(v) for k, v in d.items()}}
            for law, d in out.items()]
