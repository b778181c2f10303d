"""Entry-point discovery without importlib.metadata: the same answers as the standard
library's, on distributions laid out as pip and setuptools install them."""

from importlib import metadata

from mechdsl.plugins.discover import entry_points


def dist_info(site, folder, header, entry_points_txt):
    info = site / folder
    info.mkdir(parents=True)
    name = "PKG-INFO" if folder.endswith(".egg-info") else "METADATA"
    (info / name).write_text(header)
    if entry_points_txt is not None:
        (info / "entry_points.txt").write_text(entry_points_txt)


def stdlib(group, path):
    seen, out = set(), []
    for dist in metadata.distributions(path=path):
        key = dist.metadata["Name"].lower().replace("_", "-")
        if key in seen:  # the first of a name on the path wins
            continue
        seen.add(key)
        out += [(ep.name, ep.value, dist.name, dist.version)
                for ep in dist.entry_points if ep.group == group]
    return sorted(out)


def test_discovery_agrees_with_importlib_metadata(tmp_path):
    first, second = tmp_path / "a", tmp_path / "b"
    dist_info(first, "mechdsl_gears-1.2.dist-info",
              "Metadata-Version: 2.1\nName: mechdsl-gears\nVersion: 1.2\n\nA long description: x\n",
              "# a comment\n[console_scripts]\ngears = mechdsl_gears:main\n\n"
              "[mechdsl]\ngear = mechdsl_gears\nrack_pinion = mechdsl_gears : hooks\n")
    dist_info(first, "other-0.3.egg-info", "Metadata-Version: 1.1\nName: other\nVersion: 0.3\n",
              "[mechdsl]\ncam = other.cams:plugin\n")
    dist_info(first, "nothing-1.0.dist-info", "Metadata-Version: 2.1\nName: nothing\nVersion: 1.0\n",
              None)
    # an older copy later on the path is shadowed, as Python's import would shadow it
    dist_info(second, "mechdsl_gears-0.9.dist-info",
              "Metadata-Version: 2.1\nName: mechdsl-gears\nVersion: 0.9\n",
              "[mechdsl]\nold_gear = mechdsl_gears_old\n")
    path = [str(first), str(tmp_path / "missing"), str(second)]
    ours = sorted((e.name, e.value, e.dist_name, e.dist_version)
                  for e in entry_points("mechdsl", path))
    assert ours == stdlib("mechdsl", path)
    assert ("gear", "mechdsl_gears", "mechdsl-gears", "1.2") in ours
    assert all(e[0] != "old_gear" for e in ours)
    assert len(ours) == 3


def test_an_entry_point_loads_the_object_it_names(tmp_path, monkeypatch):
    (tmp_path / "pkg_x.py").write_text("class Hooks:\n    inner = 42\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    dist_info(tmp_path, "pkg_x-1.0.dist-info", "Name: pkg-x\nVersion: 1.0\n",
              "[mechdsl]\nx = pkg_x:Hooks.inner\ny = pkg_x : Hooks.inner [fast, extra]\n")
    eps = entry_points("mechdsl", [str(tmp_path)])
    assert [ep.load() for ep in eps] == [42, 42]
    assert eps[1].value == "pkg_x : Hooks.inner"
