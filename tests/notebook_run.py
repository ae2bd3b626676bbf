"""Running a notebook of notebooks/ in a test, as `make notebooks` runs it."""

from pathlib import Path


def executed_outputs(notebook: Path, folder: Path) -> list:
    """The outputs of every code cell of `notebook`, executed with `folder` as its working folder; none is an error."""
    import nbformat
    from nbclient import NotebookClient

    cells = nbformat.read(notebook, as_version=4)
    NotebookClient(cells, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(folder)}}).execute()
    outputs = [output for cell in cells.cells if cell.cell_type == "code" for output in cell.outputs]
    assert not [output for output in outputs if output.output_type == "error"]
    return outputs


def printed(outputs: list) -> str:
    """What the cells printed."""
    return "".join(output.get("text", "") for output in outputs if output.output_type == "stream")
