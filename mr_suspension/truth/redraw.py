"""What every truth case shares: the same truth drawn again under another programme."""

from dataclasses import asdict


class Redrawable:
    """Mixin of the truth cases (frozen dataclasses with ``record``, ``args`` and ``truth``).

    ``make`` names the function that drew the case; ``args`` are its arguments.
    """

    make = None

    def unseen(self, record=None, duration=None, **changes):
        """Return the same truth and sensors under another programme and noise.

        ``record`` defaults to this record + 1; ``duration`` and further arguments of the
        case's maker (given and not None) replace this case's.
        """
        args = dict(self.args)
        args['record'] = self.record + 1 if record is None else int(record)
        if duration is not None:
            args['duration'] = duration
        args.update({k: v for k, v in changes.items() if v is not None})
        return type(self).make(**args)

    def truth_dict(self):
        """Truth parameters as a plain dict."""
        return asdict(self.truth)
