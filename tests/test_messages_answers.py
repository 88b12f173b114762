"""The com-uuid answer history shared by the engine and the simulated units."""

from delegation.messages.answers import AnswerCache, com_uuid_of


def test_com_uuid_of_reads_only_a_string_com_uuid() -> None:
    assert com_uuid_of(b'{"com-uuid": "abc", "command": "ping"}') == "abc"
    assert com_uuid_of(b'{"com-uuid": 5}') is None
    assert com_uuid_of(b'{"com-uuid": ""}') is None
    assert com_uuid_of(b"[1, 2]") is None
    assert com_uuid_of(b"not json") is None
    assert com_uuid_of(b"\xff\xfe") is None


def test_answer_cache_answers_again_and_forgets_the_oldest() -> None:
    cache = AnswerCache(limit=2)
    cache.put("a", b"A")
    cache.put("b", b"B")
    assert cache.get("a") == b"A"
    cache.put("c", b"C")
    assert cache.get("a") is None
    assert (cache.get("b"), cache.get("c")) == (b"B", b"C")
    assert cache.get(None) is None
    cache.put("", b"ignored")
    assert len(cache) == 2
