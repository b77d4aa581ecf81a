"""Every router of the app, one module per area (each re-exports its area's ``routes``): the
app includes them all, and a test walks them (every upload route is exempt from the JSON body
limit)."""
