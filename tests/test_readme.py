"""The README opens with the two commands CI runs (.ci/run reads the first line of its first two
```bash blocks); its examples are files of examples/, run by tests/test_examples.py."""

import re

from conftest import REPO

README = (REPO / "README.md").read_text()


def test_readme_opens_with_the_two_commands():
    blocks = re.findall(r"```bash\n(.*?)\n```", README, flags=re.S)
    assert blocks[0].startswith("python -m pip install -e . && python diagrams/lego.py")
    assert "--metrics" in blocks[0] and "--record" in blocks[0]
    assert blocks[1].startswith('python -m pip install -e ".[test]"') and "pytest" in blocks[1]
