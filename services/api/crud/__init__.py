"""The API's logic: routes parse and authorise, these functions query and change the database."""
