"""Files a command owns are opened there and nowhere else: a symbolic link, a hard link or a named pipe in their
place is refused with one line, and what it points to is left as it was."""

from __future__ import annotations

import os

import pytest

from gns_framework.io.owned_files import LinkRefused, open_owned, refuse_link, write_owned_text


def test_a_new_file_is_created_then_appended_to(tmp_path):
    path = tmp_path / "metrics.jsonl"
    with open_owned(path, "a", "metrics file") as handle:
        handle.write("1\n")
    with open_owned(path, "a", "metrics file") as handle:
        handle.write("2\n")
    assert path.read_text() == "1\n2\n"
    write_owned_text(path, "3\n", "metrics file")
    assert path.read_text() == "3\n"


@pytest.mark.parametrize("mode", ["w", "a", "wb"])
def test_a_symbolic_link_is_refused_and_its_target_is_untouched(tmp_path, mode):
    target = tmp_path / "users_notes.txt"
    target.write_text("precious\n")
    link = tmp_path / "run" / "metrics.jsonl"
    link.parent.mkdir()
    link.symlink_to(target)
    with pytest.raises(
        LinkRefused, match=rf"^{link}: the metrics file is a symbolic link to {target}; gns never writes"
    ):
        open_owned(link, mode, "metrics file")
    assert target.read_text() == "precious\n"
    # A link to nowhere is refused too (creating its target would write outside the folder).
    dangling = tmp_path / "run" / "params.json"
    dangling.symlink_to(tmp_path / "elsewhere.json")
    with pytest.raises(LinkRefused, match="parameters file is a symbolic link"):
        write_owned_text(dangling, "{}", "parameters file")
    assert not (tmp_path / "elsewhere.json").exists()


def test_a_hard_link_is_refused_before_anything_is_truncated(tmp_path):
    target = tmp_path / "users_file.txt"
    target.write_text("precious\n")
    os.link(target, tmp_path / "params.json")
    with pytest.raises(LinkRefused, match=r"params\.json: the parameters file has 2 names"):
        write_owned_text(tmp_path / "params.json", "{}", "parameters file")
    assert target.read_text() == "precious\n"


def test_a_named_pipe_is_refused_without_waiting_for_a_reader(tmp_path):
    fifo = tmp_path / "metrics.jsonl"
    os.mkfifo(fifo)
    with pytest.raises(LinkRefused, match="not a regular file"):
        open_owned(fifo, "a", "metrics file")


def test_refuse_link_names_a_linked_folder(tmp_path):
    (tmp_path / "checkpoints").symlink_to(tmp_path, target_is_directory=True)
    with pytest.raises(LinkRefused, match=r"checkpoints: the run's checkpoints folder is a symbolic link"):
        refuse_link(tmp_path / "checkpoints", "run's checkpoints folder")
    refuse_link(tmp_path / "missing", "anything")  # absent: nothing to refuse
