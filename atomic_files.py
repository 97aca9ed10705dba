"""Writing outputs so that a failure writes nothing and no input is ever overwritten.

Two layers, used by every writer of the package:

* **One file** (:func:`atomic_write`, :func:`write_text`, :func:`write_bytes`): the content
  goes to a temporary file in the destination's own folder, which is flushed to disk and then
  renamed over the destination. A rename within one folder is atomic, so the destination holds
  either its old bytes or the complete new ones, never a prefix; if anything fails first, the
  temporary file is removed and the destination is untouched. A symbolic link is followed (the
  file it points to is replaced, the link stays); a character device such as ``/dev/null`` is
  written in place (it cannot be replaced, and holds nothing to lose).

* **One command** (:class:`Outputs`): a command's outputs are declared before the work starts,
  each checked at once (a folder where a file is expected, a parent that is a file, an output
  that is one of the command's input files or another of its outputs, a FIFO that would block)
  and staged: a file as a temporary file beside its destination, a report folder as a hidden
  staging folder beside it. Writers write into the staged paths; when the command succeeds,
  :meth:`Outputs.commit` renames everything into place; when it fails, :meth:`Outputs.abort`
  removes every staged file and every folder it created, so a failed command leaves nothing
  behind (not even an empty ``--out`` folder).

Errors are :class:`OutputPathError` (a ``ValueError``) naming the option as the user wrote it
(``-o``, ``--out``), the path (cut short) and the problem.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import shutil
import stat
from collections.abc import Iterator, Mapping
from pathlib import Path

from telesmooth.user_input import quote, quote_path

__all__ = [
    "OutputPathError",
    "Outputs",
    "atomic_write",
    "create_new_file",
    "display_path",
    "write_bytes",
    "write_text",
]


class OutputPathError(ValueError):
    """An output path that cannot or must not be written (the message names the option)."""


_KIND_NAMES = {stat.S_IFIFO: "a FIFO", stat.S_IFSOCK: "a socket", stat.S_IFBLK: "a block device",
               stat.S_IFCHR: "a character device", stat.S_IFDIR: "a folder"}


def _kind(mode: int) -> str:
    return _KIND_NAMES.get(stat.S_IFMT(mode), "not a regular file")


_STAGED = re.compile(r"\.[0-9a-f]{8}\.tmp-")


def display_path(path) -> str:
    """How messages show an output path: quoted, and without the names of the temporary
    files and staging folders of this module (``.1a2b3c4d.tmp-report.md`` → ``report.md``),
    so that a failure inside a staged output names the output the user asked for."""
    return quote_path(_STAGED.sub("", str(path)))


def _temporary_name(name: str) -> str:
    # Hidden, unique, and ending with the destination's name (so its suffix is kept, which
    # e.g. numpy.savez needs).
    return f".{secrets.token_hex(4)}.tmp-{name}"


def _destination(path: Path) -> Path:
    """The file actually written for ``path``: the target of a symbolic link."""
    return Path(os.path.realpath(path)) if path.is_symlink() else path


@contextlib.contextmanager
def atomic_write(path, mode: str = "w", *, newline: str | None = None,
                 encoding: str | None = "utf-8") -> Iterator:
    """Opens a temporary file beside ``path``; renames it over ``path`` on success.

    Args:
        path: The destination file. Its folder must exist. A symbolic link is followed; a
            character device is written in place.
        mode: ``"w"`` (text) or ``"wb"`` (bytes).
        newline, encoding: As for :func:`open` (text mode only).

    Yields:
        The open file. If the ``with`` block raises, the temporary file is removed and
        ``path`` keeps its old content (or stays absent).

    The new file gets the mode of the file it replaces, or 0o666 less the umask.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode = {mode!r} must be 'w' or 'wb'")
    text = {} if mode == "wb" else {"newline": newline, "encoding": encoding}
    destination = _destination(Path(path))
    try:
        existing = os.stat(destination)
    except FileNotFoundError:
        existing = None
    if existing is not None and stat.S_ISCHR(existing.st_mode):
        try:
            with open(destination, mode, **text) as handle:
                yield handle
        except OSError as error:     # e.g. /dev/full: "No space left on device"
            raise OutputPathError(f"{display_path(destination)}: cannot write it "
                                  f"({error.strerror})") from None
        return
    if existing is not None and not stat.S_ISREG(existing.st_mode):
        raise OutputPathError(f"{quote_path(str(path))} is {_kind(existing.st_mode)}, not a file")
    temporary = destination.with_name(_temporary_name(destination.name))
    file_mode = (stat.S_IMODE(existing.st_mode) if existing is not None
                 else 0o666 & ~_umask())
    try:
        descriptor = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as error:
        raise OutputPathError(f"{display_path(destination)}: cannot write it "
                              f"({error.strerror})") from None
    try:
        with open(descriptor, mode, **text) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(temporary, file_mode)
        os.replace(temporary, destination)
    except BaseException as error:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)
        if isinstance(error, OSError) and not isinstance(error, OutputPathError) \
                and error.filename is None:
            # A failed write (a full disk) names no file: name the destination.
            raise OutputPathError(f"{display_path(destination)}: cannot write it "
                                  f"({error.strerror or error})") from None
        raise


def write_text(path, text: str, *, encoding: str = "utf-8") -> None:
    """Writes ``text`` to ``path`` atomically (see :func:`atomic_write`)."""
    with atomic_write(path, "w", encoding=encoding) as handle:
        handle.write(text)


def write_bytes(path, data: bytes) -> None:
    """Writes ``data`` to ``path`` atomically (see :func:`atomic_write`)."""
    with atomic_write(path, "wb") as handle:
        handle.write(data)


def create_new_file(path, data: bytes, *, file_mode: int = 0o600) -> None:
    """Creates ``path`` with ``data`` and ``file_mode``, complete or not at all, never
    replacing anything: the bytes go to a temporary file that is then hard-linked to ``path``
    (which fails if ``path`` exists, atomically).

    Raises:
        FileExistsError: ``path`` exists (whatever it is: a file, a folder, a link, a FIFO).
        OSError: the folder cannot be written.
    """
    destination = Path(path)
    temporary = destination.with_name(_temporary_name(destination.name))
    descriptor = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        with open(descriptor, "wb") as handle:
            os.fchmod(handle.fileno(), file_mode)   # whatever the umask
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.link(temporary, destination)
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)


def _umask() -> int:
    """The process's umask, read without changing it (``os.umask`` sets it, which would race
    with other threads creating files)."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    current = os.umask(0o022)
    os.umask(current)
    return current


def _same_file(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` name one file: the same inode if both exist (hard and
    symbolic links included), else the same resolved path."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def _is_within(path: Path, folder: Path) -> bool:
    try:
        Path(os.path.realpath(path)).relative_to(os.path.realpath(folder))
    except ValueError:
        return False
    return True


class Outputs:
    """The outputs of one command, staged so that they appear together or not at all.

    Usage::

        with Outputs(inputs={"input": args.input}) as outputs:
            csv_path = outputs.file("-o", args.output)      # checked and staged now
            report_dir = outputs.folder("--out", args.out)
            ...                                             # the work; write to the paths
        # committed here if the block succeeded, else everything staged is removed

    Args:
        inputs: The command's input files, as ``{name as the user wrote it: path}``; no output
            may be one of them (nor write a file of a report folder over one). More can be
            added with :meth:`add_input` (e.g. a file a scenario names).
    """

    def __init__(self, inputs: Mapping[str, object] | None = None):
        self._inputs: dict[str, Path] = {}
        self._files: list[tuple[str, Path, Path, Path]] = []  # option, path, written, temp
        self._folders: list[tuple[str, Path, Path]] = []     # option, path, staging folder
        self._created: list[Path] = []                         # folders made for the outputs
        self._done = False
        for name, path in (inputs or {}).items():
            self.add_input(name, path)

    # --- declaring ---

    def add_input(self, name: str, path) -> None:
        """Declares an input file (``None`` is ignored); it must not be an output."""
        if path is None:
            return
        path = Path(path)
        self._inputs[name] = path
        for option, out, _, _ in self._files:
            self._check_not_input(option, out)

    def file(self, option: str, path) -> Path:
        """Checks and stages the output file ``path`` of ``option``; returns the path to
        write (a temporary file beside ``path``, or ``path`` itself for a character device
        such as ``/dev/null``).

        Raises:
            OutputPathError: ``path`` is a folder, a FIFO, socket or block device; a parent
                is a file; it is an input file or another output; its folder cannot be
                written.
        """
        path = Path(path)
        label, existing = self._examine(option, path)
        if existing is not None and stat.S_ISDIR(existing.st_mode):
            raise OutputPathError(f"{label} is a folder; give a file name")
        if existing is not None and not (stat.S_ISREG(existing.st_mode)
                                         or stat.S_ISCHR(existing.st_mode)):
            raise OutputPathError(f"{label} is {_kind(existing.st_mode)}, not a file")
        self._check_not_input(option, path)
        for other, out, _, _ in self._files:
            if _same_file(out, path):
                raise OutputPathError(f"{label} is also the output of {other}; give two "
                                      "different files")
        for other, folder, _ in self._folders:
            if _is_within(path, folder):
                raise OutputPathError(f"{label} lies in the folder of {other}; give a file "
                                      "outside it")
        if existing is not None and stat.S_ISCHR(existing.st_mode):
            self._files.append((option, path, path, path))
            return path
        destination = _destination(path)
        self._make_parents(label, destination.parent)
        temporary = destination.with_name(_temporary_name(destination.name))
        try:
            os.close(os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        except OSError as error:
            raise OutputPathError(f"{label}: cannot write in "
                                  f"{quote_path(str(destination.parent))} ({error.strerror})") \
                from None
        self._files.append((option, path, destination, temporary))
        return temporary

    def folder(self, option: str, path) -> Path:
        """Checks and stages the output folder ``path`` of ``option``; returns the staging
        folder to write the files into (a hidden folder beside ``path``). On commit each
        staged file replaces its namesake in ``path`` (other files there are kept).

        Raises:
            OutputPathError: ``path`` is a file (or another non-folder), a parent is a file,
                it is (or lies inside, or holds) another output, or its parent cannot be
                written.
        """
        path = Path(path)
        label = self._check_folder(option, path)
        for other, folder, _ in self._folders:
            if _is_within(path, folder) or _is_within(folder, path):
                raise OutputPathError(f"{label} overlaps the folder of {other}")
        parent = Path(os.path.realpath(path)).parent
        self._make_parents(label, parent)
        staging = parent / _temporary_name(path.name or "out")
        try:
            os.mkdir(staging, 0o700)
        except OSError as error:
            raise OutputPathError(f"{label}: cannot write in {quote_path(str(parent))} "
                                  f"({error.strerror})") from None
        self._folders.append((option, path, staging))
        return staging

    def work_folder(self, option: str, path) -> Path:
        """Checks the output folder ``path`` of ``option`` and makes it (with its missing
        parents) now, for a command that keeps its work there as it goes (a journal a rerun
        continues, e.g. the experiment's records): its files are written in place, each
        atomically by its writer. On abort only the folders made here that are still empty
        are removed.

        Raises:
            OutputPathError: as :meth:`folder`.
        """
        path = Path(path)
        label = self._check_folder(option, path)
        self._make_parents(label, path)
        return path

    def drop(self, staged: Path) -> None:
        """Withdraws the staged file ``staged`` (as :meth:`file` returned it): its
        destination is left as it is."""
        for index, (_, _, destination, temporary) in enumerate(self._files):
            if temporary == Path(staged):
                if temporary != destination:
                    with contextlib.suppress(FileNotFoundError):
                        os.unlink(temporary)
                del self._files[index]
                return
        raise ValueError(f"{quote_path(str(staged))} is not a staged output file")

    # --- finishing ---

    def commit(self) -> None:
        """Puts every staged output in place (files first, then folders).

        Raises:
            OutputPathError: a file of a staged folder would replace an input file, or a
                folder of that name holds a non-file (nothing is written then).
        """
        if self._done:
            return
        plans = [self._folder_plan(option, path, staging)
                 for option, path, staging in self._folders]
        for _, _, destination, temporary in self._files:
            if temporary != destination:
                os.chmod(temporary, _new_file_mode(destination))
                os.replace(temporary, destination)
        for (_option, path, staging), plan in zip(self._folders, plans):
            if plan is None:            # a new folder: one rename puts it all in place
                os.chmod(staging, 0o777 & ~_umask())
                os.rename(staging, path)
                continue
            for source, target in plan:
                if source.is_dir():
                    target.mkdir(exist_ok=True)
                else:
                    os.replace(source, target)
            shutil.rmtree(staging, ignore_errors=True)
        self._done = True

    def abort(self) -> None:
        """Removes everything staged and every folder made for it; writes nothing."""
        if self._done:
            return
        for _, _, destination, temporary in self._files:
            if temporary != destination:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(temporary)
        for _, _, staging in self._folders:
            shutil.rmtree(staging, ignore_errors=True)
        for folder in reversed(self._created):
            with contextlib.suppress(OSError):
                folder.rmdir()          # only if still empty
        self._done = True

    def __enter__(self) -> Outputs:
        return self

    def __exit__(self, kind, error, trace) -> None:
        if kind is None:
            try:
                self.commit()
            except BaseException:
                self.abort()
                raise
        else:
            self.abort()

    # --- helpers ---

    def _check_folder(self, option: str, path: Path) -> str:
        """The label of ``path`` as a folder output, after refusing a non-folder there and a
        folder that holds an output file."""
        label, existing = self._examine(option, path)
        if existing is not None and not stat.S_ISDIR(existing.st_mode):
            what = "a file" if stat.S_ISREG(existing.st_mode) else _kind(existing.st_mode)
            raise OutputPathError(f"{label} is {what}, not a folder; give a folder name")
        for other, out, _, _ in self._files:
            if _is_within(out, path):
                raise OutputPathError(f"{label} holds the output of {other}")
        return label

    def _examine(self, option: str, path: Path):
        """(the label of messages, ``os.stat`` of ``path`` or None if it does not exist)."""
        label = f"{option} = {quote_path(str(path))}"
        try:
            return label, os.stat(path)
        except FileNotFoundError:
            return label, None
        except NotADirectoryError:
            raise OutputPathError(f"{label}: {self._file_in_the_way(path)}") from None
        except OSError as error:
            raise OutputPathError(f"{label}: cannot use it ({error.strerror})") from None

    def _check_not_input(self, option: str, path: Path) -> None:
        for name, source in self._inputs.items():
            if _same_file(path, source):
                raise OutputPathError(
                    f"{option} = {quote_path(str(path))} is the input {name} = "
                    f"{quote_path(str(source))}; refusing to overwrite it")

    @staticmethod
    def _file_in_the_way(path: Path) -> str:
        for parent in reversed(path.parents):
            if parent.exists() and not parent.is_dir():
                return f"{quote_path(str(parent))} is a file, not a folder"
        return "a parent is not a folder"

    def _make_parents(self, label: str, folder: Path) -> None:
        missing = []
        for parent in (folder, *folder.parents):
            if parent.is_dir():
                break
            if parent.exists() or parent.is_symlink():
                raise OutputPathError(
                    f"{label}: {quote_path(str(parent))} is a file, not a folder")
            missing.append(parent)
        for parent in reversed(missing):
            try:
                parent.mkdir()
            except FileExistsError:
                continue
            except OSError as error:
                raise OutputPathError(f"{label}: cannot make the folder "
                                      f"{quote_path(str(parent))} ({error.strerror})") from None
            self._created.append(parent)

    def _folder_plan(self, option: str, path: Path, staging: Path):
        """``None`` for a new folder, else the (staged, destination) pairs to move, checked."""
        label = f"{option} = {quote_path(str(path))}"
        if not path.exists():
            for name, source in self._inputs.items():
                if _is_within(source, staging):   # cannot happen; defensive
                    raise OutputPathError(f"{label}: the report would replace {name}")
            return None
        plan = []
        for root, folders, files in os.walk(staging):
            for entry in sorted(folders) + sorted(files):
                source = Path(root) / entry
                target = path / source.relative_to(staging)
                if source.is_dir():
                    if target.exists() and not target.is_dir():
                        raise OutputPathError(f"{label}: {quote_path(str(target))} is a file; the "
                                              "report needs a folder there")
                else:
                    if target.is_dir():
                        raise OutputPathError(f"{label}: {quote_path(str(target))} is a folder; "
                                              "the report writes a file there")
                    for name, input_path in self._inputs.items():
                        if _same_file(target, input_path):
                            raise OutputPathError(
                                f"{label}: the report's {quote(entry)} would overwrite the "
                                f"input {name} = {quote_path(str(input_path))}; choose another "
                                "folder")
                plan.append((source, target))
        return plan


def _new_file_mode(destination: Path) -> int:
    try:
        return stat.S_IMODE(os.stat(destination).st_mode)
    except OSError:
        return 0o666 & ~_umask()
