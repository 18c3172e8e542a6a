"""What an image in QEMU logged, read by the check scripts.

`stack(text)`: the image's stack figures (fc_stm32f405::stack): the boot's
high-water mark (`stack: boot reached N bytes`, logged as the idle task
starts, before the stack is painted again) and the tasks' since then (the
last `stack: high-water N bytes of M` line, logged with the timing line when
the mark has grown), in bytes.

`link_hold(text)`: the longest the CRTP images' link task held the vehicle
(fc_stm32f405::timing::Holds: the last `link: held the vehicle up to N
instructions` line, logged with the timing line when it has grown).

`timing(text)`: the images' step figures (fc_stm32f405::timing: the last
`timing: N steps, …` line, logged every 1000 steps and at once when a step
is late), as a dict, or None if the image logged none.
"""
import re

BOOT_LINE = re.compile(r"stack: boot reached (\d+) bytes")
TASKS_LINE = re.compile(r"stack: high-water (\d+) bytes of (\d+)")
HOLD_LINE = re.compile(r"link: held the vehicle up to (\d+) instructions")
TIMING_LINE = re.compile(r"timing: (\d+) steps, worst data-ready->estimate (\d+) instructions, "
                         r"worst data-ready->answer (\d+) instructions, deadline (\d+): (\d+) missed "
                         r"\((\d+) jobs, (\d+) answers dropped, (\d+) tx timeouts\); (\d+) IMU deadlines missed; "
                         r"(\d+) steps passed during a design")
TIMING_FIELDS = ("steps", "estimate", "answer", "deadline", "missed", "jobs", "answers", "tx", "imu", "passed")


def stack(text):
    """(boot, tasks, capacity) in bytes from the image's log `text` (a
    string or a list of lines): the boot's mark, the tasks' last mark and
    the bytes the stack may grow to; 0 for a figure it did not log."""
    if not isinstance(text, str):
        text = "\n".join(text)
    boot = BOOT_LINE.findall(text)
    tasks = TASKS_LINE.findall(text)
    return (int(boot[-1]) if boot else 0,
            int(tasks[-1][0]) if tasks else 0,
            int(tasks[-1][1]) if tasks else 0)


def link_hold(text):
    """The longest hold of the vehicle by the link's task the image logged
    in `text` (a string or a list of lines), instructions; 0 if none."""
    if not isinstance(text, str):
        text = "\n".join(text)
    held = HOLD_LINE.findall(text)
    return int(held[-1]) if held else 0


def timing(text):
    """The last timing line the image logged in `text` (a string or a list
    of lines): {steps, estimate, answer, deadline, missed, jobs, answers, tx,
    imu, passed} (the worst estimate and answer in instructions), or None."""
    if not isinstance(text, str):
        text = "\n".join(text)
    found = TIMING_LINE.findall(text)
    return dict(zip(TIMING_FIELDS, (int(x) for x in found[-1]))) if found else None
