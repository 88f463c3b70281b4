% expect_error(id, fn): calls fn and asserts that it raises an error with identifier id.
function expect_error(id, fn)
  try
    fn();
  catch e
    assert(strcmp(e.identifier, id), sprintf('expected %s, got %s: %s', id, e.identifier, e.message));
    return;
  end
  error('test:fail', 'expected error %s', id);
end
